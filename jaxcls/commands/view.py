"""``jaxcls view``: open an episode's 3-D recording (``episode.rrd`` of ``jaxcls run rerun=true`` or ``jaxcls
demo``) in rerun's native viewer, or with ``--web`` serve rerun's web viewer on localhost (headless machines:
open the printed URL in a browser, through an SSH tunnel from another machine)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from jaxcls.commands import Argument, Command


def recording_file(run: str | Path) -> Path:
    """The ``.rrd`` of ``run`` (a run folder holding ``episode.rrd``, or the file); ValueError naming it."""
    path = Path(run)
    file = path / "episode.rrd" if path.is_dir() else path
    if not file.is_file():
        raise ValueError(f"{file}: no episode recording (jaxcls run rerun=true writes one into its out_dir; "
                         "jaxcls demo does by default)")
    with open(file, "rb") as f:
        if f.read(4) != b"RRF2":
            raise ValueError(f"{file}: not a rerun recording (.rrd)")
    return file


def web_url(web_port: int, grpc_port: int) -> str:
    """The address of rerun's web viewer showing the recording its gRPC server holds."""
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"


def viewer_command(file: Path, web: bool, port: int) -> list[str]:
    """The rerun command line that shows ``file`` (web: its web viewer on ``port``, gRPC on ``port`` + 1)."""
    command = [sys.executable, "-m", "rerun", str(file)]
    if web:
        command += ["--serve-web", "--web-viewer-port", str(port), "--port", str(port + 1)]
    return command


def _run(config: None, args: argparse.Namespace) -> str:
    file = recording_file(args.run)
    if not args.web and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or sys.platform in
                             ("darwin", "win32")):
        raise ValueError("no display here (DISPLAY is not set): jaxcls view --web serves the web viewer instead")
    if args.web:
        print(f"rerun's web viewer for {file}: {web_url(args.port, args.port + 1)}  (Ctrl-C stops it)", flush=True)
    done = subprocess.run(viewer_command(file, args.web, args.port), check=False)
    return f"viewer closed ({file}, exit status {done.returncode})"


COMMAND = Command(
    description="Open an episode's 3-D recording (episode.rrd: jaxcls run rerun=true, jaxcls demo) in rerun's "
                "viewer, or serve its web viewer on localhost with --web.",
    schema=None, run=_run,
    arguments=(Argument(("run",), {"help": "a run folder holding episode.rrd, or an .rrd file"}),
               Argument(("--web",), {"action": "store_true", "help": "serve the web viewer (headless machines)"}),
               Argument(("--port",), {"type": int, "default": 9090,
                                      "help": "--web: the web viewer's port (its data server uses the next one)"})),
)
