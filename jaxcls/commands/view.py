"""``jaxcls view``: open an episode's 3-D recording (``episode.rrd`` of ``jaxcls run rerun=true`` or ``jaxcls
demo``) in rerun's native viewer, or with ``--web`` serve rerun's web viewer on localhost (headless machines:
open the printed URL in a browser, through an SSH tunnel from another machine)."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
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
    done = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(file)], capture_output=True,
                          text=True, check=False)
    if done.returncode:
        reason = (done.stderr.strip().splitlines() or ["rerun rrd verify failed"])[-1]
        raise ValueError(f"{file}: a damaged rerun recording ({reason})")
    return file


def web_url(web_port: int, grpc_port: int) -> str:
    """The address of rerun's web viewer showing the recording its gRPC server holds."""
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"


def free_ports() -> int:
    """A free port P whose next one is free too (the web viewer and its data server)."""
    import socket

    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        with contextlib.suppress(OSError), socket.socket() as s:
            s.bind(("127.0.0.1", port + 1))
            return port


def viewer_command(file: Path, web: bool, port: int) -> list[str]:
    """The rerun command line that shows ``file`` (web: its web viewer on ``port``, gRPC on ``port`` + 1)."""
    command = [sys.executable, "-m", "rerun", str(file)]
    if web:
        command += ["--serve-web", "--web-viewer-port", str(port), "--port", str(port + 1)]
    return command


@contextlib.contextmanager
def serve_web(file: str | Path, port: int, timeout: float = 30.0) -> Iterator[str]:
    """rerun's web viewer for ``file`` on localhost (``port``, its data on ``port`` + 1) while the block runs:
    yields the page's URL once it answers (RuntimeError naming the port if it does not within ``timeout``);
    stops the server (and the viewer binary ``python -m rerun`` starts) after."""
    import urllib.request

    url = web_url(port, port + 1)
    server = subprocess.Popen(viewer_command(recording_file(file), True, port), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                with urllib.request.urlopen(url, timeout=2):
                    break
            except OSError:
                if server.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"rerun's web viewer did not start on port {port} (in use?)") from None
                time.sleep(0.2)
        yield url
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=20)


def _run(config: None, args: argparse.Namespace) -> str:
    file = recording_file(args.run)
    if not args.web and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or sys.platform in
                             ("darwin", "win32")):
        raise ValueError("no display here (DISPLAY is not set): jaxcls view --web serves the web viewer instead")
    port = args.port or free_ports()
    if args.web:
        print(f"rerun's web viewer for {file}: {web_url(port, port + 1)}  (Ctrl-C stops it)", flush=True)
    done = subprocess.run(viewer_command(file, args.web, port), check=False)
    return f"viewer closed ({file}, exit status {done.returncode})"


COMMAND = Command(
    description="Open an episode's 3-D recording (episode.rrd: jaxcls run rerun=true, jaxcls demo) in rerun's "
                "viewer, or serve its web viewer on localhost with --web.",
    schema=None, run=_run,
    arguments=(Argument(("run",), {"help": "a run folder holding episode.rrd, or an .rrd file"}),
               Argument(("--web",), {"action": "store_true", "help": "serve the web viewer (headless machines)"}),
               Argument(("--port",), {"type": int, "default": 9090,
                                      "help": "--web: the web viewer's port (its data server uses the next one; 0: "
                                              "any free pair)"})),
)
