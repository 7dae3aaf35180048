"""``jaxcls view``: finds a run's recording, refuses what is not one, and serves rerun's web viewer on
localhost (the page and the recording's data server answer)."""

from __future__ import annotations

import socket
import sys
import urllib.request

import numpy as np
import pytest

from jaxcls.cli import main
from jaxcls.commands.view import free_ports, recording_file, serve_web


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
    whole = (run_folder / "episode.rrd").read_bytes()
    (tmp_path / "cut.rrd").write_bytes(whole[:len(whole) // 2])  # a copy cut short
    with pytest.raises(ValueError, match=r"cut\.rrd: a damaged rerun recording"):
        recording_file(tmp_path / "cut.rrd")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform not in ("darwin", "win32"):
        assert main(["view", str(run_folder)]) == 2  # no display: names --web
        assert "--web" in capsys.readouterr().err


def test_the_web_viewer_is_served_on_localhost(run_folder):
    with serve_web(run_folder, free_ports()) as url:
        with urllib.request.urlopen(url, timeout=5) as response:
            assert "<html" in response.read().decode(errors="replace").lower()
        port = int(url.split(":")[2].split("/")[0])
        with socket.create_connection(("127.0.0.1", port + 1), timeout=5):
            pass  # the recording's data server listens where the URL points the viewer
    with pytest.raises(OSError):  # stopped after the block
        urllib.request.urlopen(url, timeout=2)
