"""``jaxcls view``: finds a run's recording, refuses what is not one, and serves rerun's web viewer on
localhost (the page and the recording's data server answer)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

from jaxcls.cli import main
from jaxcls.commands.view import recording_file, viewer_command, web_url


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def run_folder(tmp_path):
    import rerun as rr

    stream = rr.RecordingStream("jaxcls", send_properties=False)
    memory = stream.memory_recording()
    stream.set_time("move", sequence=1)
    stream.log("world/points", rr.Points3D(np.random.default_rng(0).random((10, 3))))
    stream.flush()
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "episode.rrd").write_bytes(memory.drain_as_bytes())
    return tmp_path / "run"


def test_the_recording_is_found_and_bad_ones_refused(run_folder, tmp_path, monkeypatch, capsys):
    assert recording_file(run_folder) == run_folder / "episode.rrd" == recording_file(run_folder / "episode.rrd")
    with pytest.raises(ValueError, match="no episode recording"):
        recording_file(tmp_path)
    (tmp_path / "fake.rrd").write_text("not a recording")
    with pytest.raises(ValueError, match="not a rerun recording"):
        recording_file(tmp_path / "fake.rrd")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform not in ("darwin", "win32"):
        assert main(["view", str(run_folder)]) == 2  # no display: names --web
        assert "--web" in capsys.readouterr().err


def test_the_web_viewer_is_served_on_localhost(run_folder):
    port = _free_port()
    while True:  # (the data server takes the next port)
        try:
            with socket.socket() as s:
                s.bind(("127.0.0.1", port + 1))
            break
        except OSError:
            port = _free_port()
    server = subprocess.Popen(viewer_command(recording_file(run_folder), True, port), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, env={**os.environ, "RERUN_ANALYTICS": "0"})
    try:
        page = None
        for _ in range(100):
            try:
                with urllib.request.urlopen(web_url(port, port + 1), timeout=2) as response:
                    page = response.read().decode(errors="replace")
                break
            except OSError:
                time.sleep(0.2)
        assert page is not None and "<html" in page.lower(), "the web viewer did not answer"
        with socket.create_connection(("127.0.0.1", port + 1), timeout=5):
            pass  # the recording's data server listens where the URL points the viewer
    finally:
        server.terminate()
        server.wait(timeout=20)
