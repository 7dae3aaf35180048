"""experiments/table1.py (the command line), jaxcls.experiments.table1 (its logic) and episode.protocol: an
interrupted experiment resumes without redoing or losing an episode; same seed, same numbers; the table and CSV
against hand-made episodes; bad inputs refused."""

from __future__ import annotations

import csv
import dataclasses
import gzip
import importlib.util
import json
import lzma
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxcls import io, metrics
from jaxcls.config import ConfigError, load_config, save_config
from jaxcls.episode import protocol
from jaxcls.experiments.table1 import data, runner, tables
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.scoring import format_share
from jaxcls.planning import nbv
from jaxcls.world.objects import ObjectSetConfig, object_set_from_config

ROOT = Path(__file__).parent.parent


@pytest.fixture(scope="module")
def table1():
    """The command line, ``experiments/table1.py``, loaded from its file (the folder is not a package)."""
    spec = importlib.util.spec_from_file_location("table1", ROOT / "experiments" / "table1.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["table1"] = module
    spec.loader.exec_module(module)
    return module


def _small(tmp: Path, out: str, *extra: str, classifiers: str = "{shipped: ''}") -> list[str]:
    """A 2-scene, 12-view synthetic set at half the Kinect's resolution; 2 runs of 2 moves of a policy row and
    the all-views row, the batched rows a scene at a time; the shipped weights only (``table1_synthetic`` adds
    the paper's: overrides merge into a mapping)."""
    config = tmp / "table1.yaml"
    config.write_text(f"out_dir: {tmp / out}\ndataset: synthetic\nruns: 2\nmoves: 2\ntiming_moves: 0\nscene_chunk: 1\n"
                      f"resamples: 100\nrows: [vis_occl_hist_gr, full_gr]\nclassifiers: {classifiers}\n"
                      "dataset_overrides: [num_scenes=2, viewpoints.count=12, backend=mujoco, camera.width=320, "
                      "camera.height=240, camera.fx=262.5, camera.fy=262.5, camera.cx=159.5, camera.cy=119.5, "
                      f"out_dir={tmp / 'data'}]\n")
    return ["--config", str(config), f"out_dir={tmp / out}", *extra]


def test_jsonl_log_drops_a_torn_line_and_appends_cleanly(tmp_path):
    path = tmp_path / "log.jsonl"
    io.append_jsonl(path, [{"a": 1}, {"a": 2}])
    with open(path, "a") as f:
        f.write('{"a": 3, "b"')  # an append cut short
    assert io.read_jsonl(path) == [{"a": 1}, {"a": 2}]
    io.append_jsonl(path, [{"a": 4}])
    assert io.read_jsonl(path) == [{"a": 1}, {"a": 2}, {"a": 4}]
    path.write_text('{"a": 1}\nnot json\n{"a": 2}\n')
    with pytest.raises(ValueError, match="line 2"):
        io.read_jsonl(path)
    # A torn line far from the end of a long log (the cut looks back past one block).
    io.write_text(path, "".join(f'{{"n": {i}}}\n' for i in range(20_000)) + '{"n": "torn' + " " * 70_000)
    io.append_jsonl(path, [{"n": "next"}])
    assert [r["n"] for r in io.read_jsonl(path)][-2:] == [19_999, "next"]


def _archive(path: Path, suffix: str) -> Path:
    """``path`` compressed beside it as ``xz -k`` / ``gzip -k`` make it (Python's module where the tool is missing)."""
    tool, module = {".xz": ("xz", lzma), ".gz": ("gzip", gzip)}[suffix]
    archive = path.with_name(path.name + suffix)
    if shutil.which(tool):
        subprocess.run([tool, "-k", str(path)], check=True)
    else:
        with module.open(archive, "wb") as f:
            f.write(path.read_bytes())
    return archive


def test_an_archived_log_reads_as_the_log(tmp_path):
    """A log compressed by ``xz -k`` or ``gzip -k`` (a finished run's records kept in results/) reads as the log
    itself, its torn last line left out too; a damaged line is named in the archive."""
    path = tmp_path / "episodes.jsonl"
    io.append_jsonl(path, [{"a": 1, "b": [1, 2]}, {"a": 2}])
    with open(path, "a") as f:
        f.write('{"a": 3, "b"')
    for suffix in (".xz", ".gz"):
        archive = _archive(path, suffix)
        assert io.read_jsonl(archive) == io.read_jsonl(path) == [{"a": 1, "b": [1, 2]}, {"a": 2}]
        archive.unlink()
    path.write_text('{"a": 1}\nnot json\n')
    with pytest.raises(ValueError, match=r"episodes\.jsonl\.xz: line 2"):
        io.read_jsonl(_archive(path, ".xz"))


def test_local_processes_get_a_gpu_each_and_a_failed_one_stops_them_all(table1, tmp_path, capsys):
    from jaxcls.experiments.table1 import local

    for argv, message in [(["--local-processes", "2", "--tables-only"], "leave out --distributed"),
                          (["--local-processes", "0"], "at least 1"),
                          (["--processes", "2", "--process-id", "2"], "0 <= I < N"),
                          (["--processes", "2"], "0 <= I < N"),
                          (["--processes", "2", "--process-id", "0", "--tables-only"], "episodes only")]:
        with pytest.raises(SystemExit):
            table1.main(argv)
        assert message in capsys.readouterr().err

    assert local.visible_gpus(2, {}) == ["0", "1"]
    assert local.visible_gpus(2, {"CUDA_VISIBLE_DEVICES": "3,5,6"}) == ["3", "5"]
    with pytest.raises(ValueError, match="CUDA_VISIBLE_DEVICES lists 1 GPU"):
        local.visible_gpus(2, {"CUDA_VISIBLE_DEVICES": "4"})
    gpu = "import os; print('gpu', os.environ['CUDA_VISIBLE_DEVICES'], flush=True)"
    # Process 0 fails once process 1 has written its line (else, on a loaded machine, process 1 can be stopped
    # before its interpreter has started, its log empty).
    started = tmp_path / "process.1.log"
    wait = (f"import pathlib, time; p = pathlib.Path({str(started)!r}); "
            "[time.sleep(0.05) for _ in range(400) if not (p.exists() and p.read_text().strip())]")
    lines = [[sys.executable, "-c", f"{gpu}; {wait}; raise SystemExit(3)"],
             [sys.executable, "-c", f"{gpu}; import time; time.sleep(60)"]]
    began = time.perf_counter()
    with pytest.raises(RuntimeError, match=r"process 0 of 2 failed \(exit status 3\).*process\.0\.log:\ngpu 7"):
        local.run(local.start(lines, ["7", "8"], tmp_path), lambda: [tmp_path / "episodes.0.jsonl"], 4, 0,
                  show_progress=False, poll_seconds=0.1)
    assert time.perf_counter() - began < 30  # the sleeping one was stopped, not waited for
    assert (tmp_path / "process.1.log").read_text().strip() == "gpu 8"
    io.append_jsonl(tmp_path / "episodes.1.jsonl", [{"a": 1}, {"a": 2}])
    done = local.run(local.start([[sys.executable, "-c", "pass"]], ["0"], tmp_path),
                     lambda: [tmp_path / "episodes.1.jsonl"], 2, 0, show_progress=False, poll_seconds=0.1)
    assert done == [{"a": 1}, {"a": 2}]


def test_local_processes_start_before_jax_only_where_that_is_safe(tmp_path, monkeypatch):
    """``local.start_early``: the processes of a config that draws its scenes on the device and names its out_dir
    start at once, with the command lines the launcher would give them; a dataset config (rendered first by the
    launcher), another flag or no --config leave the start to the launcher's checks."""
    from jaxcls.experiments.table1 import local

    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    script = tmp_path / "child.py"  # (a process that writes its arguments and GPU)
    script.write_text("import os, sys, pathlib; pathlib.Path(__file__).with_name(sys.argv[-1] + '.args').write_text("
                      "' '.join(sys.argv[1:]) + ' gpu=' + os.environ['CUDA_VISIBLE_DEVICES'])\n")
    config = tmp_path / "t.yaml"
    config.write_text(f"out_dir: {tmp_path / 'out'}\nscene_source: device\n")
    assert local.start_early(["--config", str(config), "--local-processes", "2", "--tables-only"], script) is None
    assert local.start_early(["--config", str(config)], script) is None
    assert local.start_early(["--local-processes", "2", "scenes=3"], script) is None  # (the default: a dataset)
    assert local.start_early(["--config", str(config), "--local-processes", "2", "scene_source=dataset"],
                             script) is None
    started = local.start_early(["--config", str(config), "scenes=3", "--local-processes", "2"], script)
    assert started is not None and started.out == tmp_path / "out"
    assert started.command_lines == local.commands(script, ["--config", str(config), "scenes=3"], 2)
    for p in started.processes:
        assert p.wait(timeout=60) == 0
    started.stop()
    assert sorted(f.read_text() for f in tmp_path.glob("*.args")) == [
        f"--config {config} scenes=3 --processes 2 --process-id {i} gpu={i}" for i in range(2)]


def test_a_follower_reads_logs_as_other_processes_append_to_them(tmp_path):
    """The records process 0 reads while the others append (``io.JsonlFollower``): each log's records, once,
    in order, a torn last line left out; a file that appears later is read too; then ``of_config`` keeps a
    config's episodes once each."""
    a, b = tmp_path / "episodes.1.jsonl", tmp_path / "episodes.2.jsonl"
    follower = io.JsonlFollower(lambda: sorted(tmp_path.glob("episodes.*.jsonl")), interval=0.01)
    for i in range(30):
        io.append_jsonl(a, [{"i": i}])
        if i % 3 == 0:
            io.append_jsonl(b, [{"i": -i}, {"i": -i - 1}])
        with open(a, "a") as f:  # (half an append: the next append cuts it off)
            f.write('{"i": ')
        time.sleep(0.002)
    records = follower.finish()
    assert records == io.read_jsonl(a) + io.read_jsonl(b)
    assert [r["i"] for r in records[:30]] == list(range(30)) and len(records) == 30 + 20

    config = Table1Config(rows=("random_gr", "oracle_gr"), classifiers={"shipped": ""}, scenes=2, oracle_scenes=1)
    record = {"classifier": "shipped", "row": "random_gr", "scene": 0, "run": 0}
    kept = data.of_config(config, [record, {**record, "start": 3}, {**record, "run": 1},
                                   {**record, "scene": 2}, {**record, "classifier": "paper"},
                                   {**record, "row": "random"}, {**record, "row": "oracle_gr", "scene": 1},
                                   {**record, "row": "oracle_gr"}])
    assert kept == [record, {**record, "run": 1}, {**record, "row": "oracle_gr"}]


def test_interrupted_experiment_resumes_and_the_same_seed_gives_the_same_numbers(table1, tmp_path, monkeypatch):
    """An interrupted run resumes without redoing or losing an episode; the same scenes rendered where the
    episodes run, in one process or split between two, give the same records; the tables of every process's
    store. The two episode programs (the policy rows' and PointNetFull's) compile once, ~12 s each on the
    2-core CPU, and every later run uses them: the runner frees every compiled program after each pass over
    the scenes (vm.max_map_count), so the split runs next to the interrupted run (whose program it uses),
    "a"'s resumed run keeps its programs, and "d", which checks that they are freed, runs last. Every run
    fuses its frames at the poses given (resuming and same-seed records are the subject, not tracking, as in
    the oracle's test below): the programs compile in about half the time (~25 s each tracked)."""
    untracked = "perception.tracking.mode=reported"
    argv = _small(tmp_path, "a", untracked)
    real_append = io.append_jsonl
    calls = []

    def interrupted(path, records):
        calls.append(len(records))
        if len(calls) == 2:
            raise KeyboardInterrupt  # stopped after the first batch of episodes was stored
        return real_append(path, records)

    monkeypatch.setattr(io, "append_jsonl", interrupted)
    with pytest.raises(KeyboardInterrupt):
        table1.main(argv)
    monkeypatch.setattr(io, "append_jsonl", real_append)
    store = tmp_path / "a" / "episodes.jsonl"
    first = io.read_jsonl(store)
    assert len(first) == calls[0] == 2  # scene 0's two runs of the policy row
    with open(store, "a") as f:
        f.write('{"classifier": "shipped", "row"')  # and a record torn by the interruption

    # Two processes' shares, as a jax.distributed run splits the scenes (s to process s % 2), each appending to its
    # own store, the scenes rendered where the episodes run: checked below against one process's records. (Run
    # here, with the policy rows' program the interrupted run compiled.)
    # Their first frames made after the classifiers load, on the main thread (``runner.FRAMES_AHEAD``: off, as
    # by default where a CPU renders them); "d" below, whose records they must give, makes them on a thread while
    # its classifiers load.
    split_argv = _small(tmp_path, "s", untracked, "scene_source=device", "rows=[vis_occl_hist_gr]")
    split = load_config(Table1Config, split_argv[1], split_argv[2:])
    dataset, scene_set = data.open_scenes(split)
    chunks = []  # (made on the frames thread?, the scenes) of every Scenes.chunk
    chunk = data.Scenes.chunk
    monkeypatch.setattr(data.Scenes, "chunk", lambda self, indices: chunks.append(
        (threading.current_thread().name.startswith("jaxcls-frames"), tuple(indices))) or chunk(self, indices))
    with monkeypatch.context() as m:
        m.setattr(runner, "FRAMES_AHEAD", False)
        returned = [runner.run_episodes(split, scene_set, dataset, tmp_path / "s" / "episodes.jsonl",
                                        show_progress=False, process=(index, 2)) for index in (0, 1)]
    assert chunks == [(False, (0,)), (False, (1,))], chunks
    shares = [io.read_jsonl(tmp_path / "s" / f"episodes.{index}.jsonl") for index in (0, 1)]

    with monkeypatch.context() as m:  # (its programs kept for "d": see the docstring)
        m.setattr(jax, "clear_caches", lambda: None)
        table1.main(argv)
    records = io.read_jsonl(store)
    keys = [(r["classifier"], r["row"], r["scene"], r["run"]) for r in records]
    assert len(keys) == len(set(keys)) == 2 * (2 + 1)  # 2 scenes x (2 runs + the all-views episode)
    assert records[:2] == first  # nothing redone
    table1.main(argv)  # a complete run: nothing to do, nothing added
    assert io.read_jsonl(store) == records
    times = json.loads((tmp_path / "a" / "run_times.json").read_text())  # the run that ran episodes, phase by phase
    assert [t["episodes"] for t in times] == [4]
    phases = times[0]["phases_s"]
    assert {table1.STARTUP, "start-up (classifiers, stored episodes)", "tables and figure"} <= set(phases)
    assert 0 < sum(phases.values()) <= times[0]["total_s"] + 0.2  # (disjoint phases, each rounded)
    marks = times[0]["marks_s"]  # (this process's age: pytest's; the cache is off here: no programs loaded ahead)
    assert 0 < marks[runner.CLASSIFIERS_LOADED] <= marks[runner.FIRST_CALL_DISPATCHED]
    assert runner.PROGRAMS_LOADED not in marks

    # The same scenes drawn from the dataset config and rendered where the episodes run (the scene bank; MuJoCo's
    # C caster on a CPU), none read from the files, one compiled program per pass over the scenes (as on a CPU with
    # many rows): the same records, and every program's memory maps freed afterwards (vm.max_map_count): those of
    # the programs it ran ("a"'s, held until now: ~1,700 maps together here, untracked) are gone.
    monkeypatch.setattr(runner, "CPU_PROGRAMS_PER_PASS", 1)
    assert runner.passes([1, 2, 3], "cpu") == [[1], [2], [3]] and runner.passes([1, 2, 3], "gpu") == [[1, 2, 3]]
    maps_before = _memory_maps()
    chunks.clear()
    monkeypatch.setattr(runner, "FRAMES_AHEAD", True)  # (by default only where a device renders them)
    table1.main(_small(tmp_path, "d", untracked, "scene_source=device"))
    maps_after = _memory_maps()
    # The batched rows' first chunk (scene 0) made on the frames thread while the classifiers loaded, used and
    # not made again; the second on the main thread; then PointNetFull's, scene by scene.
    assert chunks == [(True, (0,)), (False, (1,)), (False, (0,)), (False, (1,))], chunks
    print("memory maps before and after a run:", maps_before, maps_after)
    if maps_before is not None:
        assert maps_after < maps_before - 1000
    rendered = io.read_jsonl(tmp_path / "d" / "episodes.jsonl")
    order = sorted(range(len(records)), key=lambda i: keys[i])
    assert sorted(rendered, key=lambda r: (r["classifier"], r["row"], r["scene"], r["run"])) == [records[i]
                                                                                                  for i in order]
    # The two processes' shares: together the records of one process. Then two real processes (jax.distributed
    # over localhost) make the tables of every store: process 0 writes them, after the barrier.
    # Each returns what was stored when it began and what it added: process 1 began after process 0 ended.
    assert returned == [shares[0], shares[0] + shares[1]]
    assert [{r["scene"] for r in share} for share in shares] == [{0}, {1}]
    assert not (tmp_path / "s" / "episodes.jsonl").exists()
    assert (sorted(shares[0] + shares[1], key=lambda r: (r["scene"], r["run"]))
            == sorted((r for r in rendered if r["row"] == "vis_occl_hist_gr"), key=lambda r: (r["scene"], r["run"])))
    with socket.socket() as s:  # a free port for the coordinator
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    command = [sys.executable, str(ROOT / "experiments" / "table1.py"), *split_argv, "--tables-only", "--distributed",
               "--coordinator", f"localhost:{port}", "--processes", "2", "--process-id"]
    processes = [subprocess.Popen([*command, str(index)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                 for index in (0, 1)]
    try:
        logs = [p.communicate(timeout=240)[0] for p in processes]
    finally:
        for p in processes:  # none left holding the coordinator's port
            p.kill()
    assert [p.returncode for p in processes] == [0, 0], logs
    assert "4 episodes in" in logs[0] and "episodes in" not in logs[1]  # process 0 alone made the tables
    assert "| VisOcclHistGR |" in (tmp_path / "s" / "table.md").read_text()
    # --local-processes: this process starts the processes (one a GPU, no jax.distributed), waits for them and makes
    # the tables from their stores. (Both shares stored already: each process finds its share done, ~6 s; running
    # a share is ``run_episodes(process=...)``, checked above.)
    local_out = tmp_path / "l"
    local_out.mkdir()
    for index in (0, 1):
        (local_out / f"episodes.{index}.jsonl").write_bytes((tmp_path / "s" / f"episodes.{index}.jsonl").read_bytes())
    result = subprocess.run([sys.executable, str(ROOT / "experiments" / "table1.py"), *split_argv,
                             f"out_dir={local_out}", "--local-processes", "2"], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert [io.read_jsonl(local_out / f"episodes.{index}.jsonl") for index in (0, 1)] == shares  # (nothing redone)
    assert "4 episodes in" in result.stderr and "| VisOcclHistGR |" in (local_out / "table.md").read_text()
    assert all((local_out / f"process.{index}.log").exists() for index in (0, 1))
    for r in records:
        assert len(r["refined"]) == (2 if r["row"] == "vis_occl_hist_gr" else 1)
        assert len(r["true"]) == 5 and all(len(labels) == 5 for labels in r["refined"])
    out = tmp_path / "a"
    assert (out / "figure4.png").stat().st_size > 0 and "VisOcclHistGR" in (out / "table.md").read_text()
    with open(out / "table.csv") as f:
        table = list(csv.DictReader(f))
    assert [(r["row"], r["move"]) for r in table] == [("vis_occl_hist_gr", "1"), ("vis_occl_hist_gr", "2"),
                                                      ("full_gr", "1")]
    assert json.loads((out / "episodes.jsonl").read_text().splitlines()[0])["scene"] == 0
    with pytest.raises(ValueError, match=r"keys \[.runs.\] differ"):  # another config's episodes are not mixed in
        table1.main(_small(tmp_path, "a", untracked, "runs=3"))


def test_the_oracle_bounds_a_policy_one_move_ahead(table1, tmp_path):
    """From the same start, the oracle's second move scores at least the F1 of VisOcclHistGR's second move:
    both share the first move, and the policy's pick is one of the candidates the oracle scores. So it does
    with the runs tried one at a time (the CPU's default) and with two scenes' runs in one vmapped call
    (``oracle_runs_per_call``, each run against its own scene's frames and objects)."""
    # The paper-recipe weights, whose labels change from view to view, and every view a candidate (12 views
    # are too sparse for the 0.5 m radius): candidates differ in F1. Frames fused at the poses given, as where
    # test_episode.py and test_batched.py compare two compiled programs: a tracked pose differs between the
    # oracle's programs (one run a call, two a call) and the policy's in its last float32 digits, which moves
    # the fused surface chaotically downstream; and the programs compile in half the time (~10 s, not ~25 s,
    # on the 2-core CPU: five of them here).
    argv = _small(tmp_path, "o", "runs=1", "scene_chunk=2", "rows=[vis_occl_hist_gr,oracle_gr]", "oracle_scenes=2",
                  "nbv.radius=2.0", "perception.tracking.mode=reported", classifiers="{paper: builtin_paper}")
    table1.main(argv)
    # A process's share of the oracle's calls (the second of two, one episode a call as in "o"): its one scene's
    # frames padded to the run's two (the same program's shape, kept from "o": nothing compiles).
    table1.main([*argv, "rows=[oracle_gr]", f"out_dir={tmp_path / 'o3'}", "--processes", "2", "--process-id", "1"])
    table1.main([*argv, "rows=[oracle_gr]", "oracle_runs_per_call=2", f"out_dir={tmp_path / 'o2'}"])
    records = {(r["row"], r["scene"]): r for r in io.read_jsonl(tmp_path / "o" / "episodes.jsonl")}
    assert len(records) == 4
    together = {r["scene"]: r for r in io.read_jsonl(tmp_path / "o2" / "episodes.jsonl")}
    assert sorted(together) == [0, 1]
    assert json.loads((tmp_path / "o2" / "run_times.json").read_text())[-1]["episodes"] == 2  # (the oracle's count)
    classes = len(object_set_from_config(ObjectSetConfig()).classes)  # the synthetic set's, the builtin one

    def f1(r):
        return metrics.classification_scores(np.asarray(r["true"]), np.asarray(r["refined"][1]), classes).f1

    for oracles in ({scene: records["oracle_gr", scene] for scene in range(2)}, together):
        gains = []
        for scene, oracle in oracles.items():
            policy = records["vis_occl_hist_gr", scene]
            assert oracle["true"] == policy["true"]  # (each run scored against its own scene's objects)
            assert oracle["path"][0] == policy["path"][0] and oracle["refined"][0] == policy["refined"][0]
            assert len(oracle["path"]) == 2 and oracle["path"][1] != oracle["path"][0]
            gains.append(f1(oracle) - f1(policy))
        print("oracle - policy F1 after move 2, per scene:", gains)
        assert min(gains) >= -1e-9
    assert records["oracle_gr", 0]["true"] != records["oracle_gr", 1]["true"]  # (two scenes of other objects)
    # Batches of other sizes may round differently and break a tie between candidates otherwise (seen: one
    # run of four, one at a time against two a call, took another of two candidates of equal F1); the best F1
    # found is the same.
    assert [f1(together[s]) for s in range(2)] == pytest.approx([f1(records["oracle_gr", s]) for s in range(2)])
    (share,) = io.read_jsonl(tmp_path / "o3" / "episodes.1.jsonl")
    assert share == records["oracle_gr", 1]  # (the same call, whatever the process count)
    # With the compilation cache on, each program is loaded on a background thread before its first call (its
    # frames' shapes known, not the frames): the batched and the oracle's programs, one each, are what the calls
    # ran (a signature of its own would make a third), and they give the records of the run without the cache.
    # Where the renderer forbids a load beside a render (MuJoCo Warp's own graph capture: its renders fail beside
    # one on a GPU), no load ran while frames were being made, and no frames were made ahead; elsewhere (here the
    # CPU's: allowed) they may.
    for guarded in (True, False):
        out = tmp_path / f"cached_{guarded}"
        cached = _cached_run(tmp_path, [*argv, f"out_dir={out}"], guarded)
        assert cached["programs"] == 2 and not cached["warnings"], cached
        assert cached["loads"] == 2 and cached["frames"] >= 2, cached
        assert cached["overlaps"] == 0 or not guarded, cached
        # The batched rows' first frames made on the frames thread while the classifiers loaded, only where
        # the renderer allows work beside its renders; every later chunk on the main thread.
        on_thread = [name.startswith("jaxcls-frames") for name in cached["threads"]]
        assert on_thread == [not guarded] + [False] * (len(on_thread) - 1), cached
        assert io.read_jsonl(out / "episodes.jsonl") == io.read_jsonl(tmp_path / "o" / "episodes.jsonl")
        print(f"loads beside renders {'forbidden' if guarded else 'allowed'}: {cached['overlaps']} overlaps")


# ``experiments/table1.py`` in a process of its own with the compilation cache on; prints the programs kept
# (``compile_cache.exported``), the warnings about loading one ahead, the loads ahead and the frames made
# (``Scenes.chunk``), and how many of those overlapped in time.
_CACHED = """
import importlib.util, json, sys, threading, time, warnings
import jax
from jaxcls import compile_cache
from jaxcls.experiments.table1 import data, runner
spans = {{"loads": [], "frames": []}}

def timed(kind, work):
    began = time.monotonic()
    try:
        return work()
    finally:
        spans[kind].append((began, time.monotonic()))

if {guarded!r}:  # a renderer that forbids a load beside a render (MuJoCo Warp's own graph capture)
    data.Scenes.loads_beside_renders = lambda self: False
runner.FRAMES_AHEAD = True  # (the first frames made on a thread where the renderer allows: not by default on a CPU)
chunk, ahead = data.Scenes.chunk, compile_cache.ahead
threads = []  # the thread that made each chunk of frames

def made(self, indices):
    threads.append(threading.current_thread().name)
    return timed("frames", lambda: jax.block_until_ready(chunk(self, indices)))

data.Scenes.chunk = made
compile_cache.ahead = lambda load, what: ahead(lambda: timed("loads", load), what)
spec = importlib.util.spec_from_file_location("table1", {script!r})
table1 = importlib.util.module_from_spec(spec)
spec.loader.exec_module(table1)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    table1.main({argv!r})
overlaps = sum(a < d and c < b for a, b in spans["loads"] for c, d in spans["frames"])
print(json.dumps({{"programs": len(compile_cache._exported), "loads": len(spans["loads"]),
                  "frames": len(spans["frames"]), "overlaps": overlaps, "threads": threads,
                  "warnings": [str(w.message) for w in caught if "ahead" in str(w.message)]}}))
"""


def _cached_run(tmp_path: Path, argv: list[str], guarded: bool = False) -> dict:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "JAXCLS_CACHE_DIR": str(tmp_path / "xla")}
    done = subprocess.run([sys.executable, "-c", _CACHED.format(script=str(ROOT / "experiments" / "table1.py"),
                                                                 argv=argv, guarded=guarded)],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _memory_maps() -> int | None:
    """The process's memory maps (Linux), None elsewhere."""
    maps = Path("/proc/self/maps")
    return sum(1 for _ in maps.open()) if maps.exists() else None


def _record(row: str, scene: int, run: int, true: list[int], labels: list[list[int]]) -> dict:
    return {"classifier": "c", "row": row, "scene": scene, "run": run, "start": run, "path": list(range(len(labels))),
            "true": true, "prior": labels, "refined": labels}


def test_a_run_marks_when_its_loads_are_done_not_when_it_waits_for_them(monkeypatch):
    """``mark_when_done`` marks once, when the last of its futures is done (on whichever thread finishes it), at
    the process's age then; none for no futures."""
    from concurrent.futures import Future

    ages = iter([5.0, 7.0, 9.0])
    monkeypatch.setattr(runner.report, "process_age", lambda: next(ages))
    clock = runner.Phases()
    futures = [Future() for _ in range(3)]
    runner.mark_when_done(futures, clock, "loaded")
    runner.mark_when_done([], clock, "nothing")
    futures[2].set_result(None)
    threading.Thread(target=futures[0].set_result, args=(None,)).start()
    time.sleep(0.1)
    assert clock.marks == {}  # (one still loading)
    futures[1].set_exception(RuntimeError("a failed load is done too"))
    assert clock.marks == {"loaded": 5.0}  # (the age when the last was done; asked once)


def test_each_classifiers_programs_loaded_ahead_have_the_whole_runs_shapes_and_policies(monkeypatch):
    """``run_episodes`` loads each classifier's batched programs as soon as it is loaded: those of one classifier
    take the frames, call size and policies of the whole run's ``todo`` (what ``run_batched`` calls them with),
    not of that classifier's share of it (e.g. a resumed run where one classifier has less left); one program a
    (classifier, model library), only the classifiers given."""
    import types

    from jaxcls.world.dataset import DatasetConfig

    config = Table1Config(rows=("random_gr", "vis_occl_hist_gr"), classifiers={"a": "", "b": ""}, runs=2, scenes=6,
                          scene_chunk=4)
    todo = [("a", row, s, r) for s in range(6) for row in config.rows for r in range(2)]
    todo += [("b", "random_gr", s, r) for s in (4, 5) for r in range(2)]  # (b: two scenes of one row left)
    prepared = []
    monkeypatch.setattr(runner.compile_cache, "enabled", lambda: True)
    monkeypatch.setattr(runner.compile_cache, "ahead", lambda load, what: (load(), what)[1])
    monkeypatch.setattr(runner, "episode", lambda config, row, classifier, *rest, name: types.SimpleNamespace(
        switched=lambda policies: (classifier, policies)))
    monkeypatch.setattr(runner.batched, "prepare", lambda program, frames, size, mesh, **kw: prepared.append(
        (program, frames, size)))
    scenes = types.SimpleNamespace(frame_layout=lambda: (types.SimpleNamespace(height=4, width=5), 0.0, 12))
    loads = {c: runner.load_batched_ahead(config, scenes, DatasetConfig(), {c: c.upper()}, None, todo, 6)
             for c in ("b", "a")}
    assert {c: len(v) for c, v in loads.items()} == {"b": 1, "a": 1}  # (one model library here)
    per, per_call, _ = runner.chunk_plan(config, list(range(6)), 6, 1)
    policies = (protocol.ROWS["random_gr"].policy, protocol.ROWS["vis_occl_hist_gr"].policy)
    whole = ((per, 12, 4, 5), per_call * config.runs)
    assert prepared == [(("B", policies), *whole), (("A", policies), *whole)], prepared
    monkeypatch.setattr(runner.compile_cache, "enabled", lambda: False)
    assert runner.load_batched_ahead(config, scenes, DatasetConfig(), {"a": "A"}, None, todo) == []  # (no cache)


def test_a_classifiers_first_call_waits_for_its_own_programs_alone(monkeypatch, tmp_path):
    """``run_batched`` dispatches a classifier's first call once that classifier's programs are loaded, while
    the next classifier's still load (its first call then waits for them); where the renderer forbids a load
    beside a render, every load is done before the first render."""
    import types
    from concurrent.futures import Future

    from tqdm.auto import tqdm

    from jaxcls.world.dataset import DatasetConfig

    config = Table1Config(rows=("vis_occl_hist_gr",), classifiers={"a": "", "b": ""}, runs=1, moves=1, scenes=2,
                          scene_chunk=2)
    todo = [(c, "vis_occl_hist_gr", s, 0) for c in ("a", "b") for s in range(2)]
    seen = []  # (what happened, whether b's programs were loaded then)
    monkeypatch.setattr(runner, "episode", lambda config, row, classifier, *rest, name: types.SimpleNamespace(
        switched=lambda policies: types.SimpleNamespace(choose=lambda policy, gr: classifier)))
    monkeypatch.setattr(runner.scoring.Truth, "from_scene", staticmethod(lambda scene, object_set: scene))
    monkeypatch.setattr(runner.protocol, "episode_records", lambda traces, truths, extra: extra)
    monkeypatch.setattr(runner.batched, "fetch", lambda traces, n: traces)

    lock = threading.Lock()

    def settle(future: Future) -> None:  # (b's load done, once)
        with lock:
            if not future.done():
                future.set_result(None)

    for beside in (True, False):
        loads = {"a": Future(), "b": Future()}
        loads["a"].set_result(None)
        seen.clear()

        def dispatch(chosen, depth, T_wc, scene, start, key, mesh, size, loads=loads, **kw):
            seen.append((f"call {chosen}", loads["b"].done()))
            if chosen == "A":  # (b's programs done a moment after a's first call went out)
                threading.Timer(0.3, settle, (loads["b"],)).start()
            return {"path": np.zeros((size, 1), np.int32)}

        def chunk(order, loads=loads):
            seen.append(("render", loads["b"].done()))
            S = len(order)
            return data.Chunk(scenes=[types.SimpleNamespace(table_height=0.0)] * S, intrinsics=None,
                              depth=np.zeros((S, 2, 3, 4), np.float32), T_wc=np.zeros((S, 2, 4, 4), np.float32))

        # Where loads may run beside renders, b's load ends only after a's first call (a call that waited for it
        # would wait for this timer: 60 s); elsewhere it ends a moment after the run starts.
        done_later = threading.Timer(60.0 if beside else 0.2, settle, (loads["b"],))
        done_later.start()
        monkeypatch.setattr(runner.batched, "dispatch", dispatch)
        scenes = types.SimpleNamespace(loads_beside_renders=lambda beside=beside: beside, prepare_renderer=lambda: None,
                                       chunk=chunk)
        try:
            made = runner.run_batched(config, scenes, DatasetConfig(), {"a": "A", "b": "B"}, None, todo,
                                      tmp_path / f"{beside}.jsonl", tqdm(disable=True),
                                      loading={c: [f] for c, f in loads.items()})
        finally:
            done_later.cancel()
        assert sorted(runner.record_key(r) for r in made) == sorted(todo)
        if beside:  # (b's first call waited for b's load, which a's call started)
            assert seen == [("render", False), ("call A", False), ("call B", True)], seen
        else:
            assert seen == [("render", True), ("call A", True), ("call B", True)], seen


def test_the_classifiers_left_out_of_the_start_load_once_the_first_call_is_out(monkeypatch, tmp_path):
    """``run_batched``'s ``more`` (``run_episodes``: the classifiers other than the first call's) is called once
    the first call is dispatched, before the next one (a's second program's), and b's first call then waits for
    the programs it started;
    where the first call itself needs a classifier left out, ``more`` comes before it."""
    import types
    from concurrent.futures import Future

    from tqdm.auto import tqdm

    from jaxcls.world.dataset import DatasetConfig

    config = Table1Config(rows=("random_gr", "vis_occl_hist_gr"), classifiers={"a": "", "b": ""}, runs=1, moves=1,
                          scenes=2, scene_chunk=2)
    seen = []
    monkeypatch.setattr(runner, "episode", lambda config, row, classifier, *rest, name: types.SimpleNamespace(
        switched=lambda policies: types.SimpleNamespace(choose=lambda policy, gr: classifier)))
    monkeypatch.setattr(runner.scoring.Truth, "from_scene", staticmethod(lambda scene, object_set: scene))
    monkeypatch.setattr(runner.protocol, "episode_records", lambda traces, truths, extra: extra)
    monkeypatch.setattr(runner.batched, "fetch", lambda traces, n: traces)
    monkeypatch.setattr(runner.batched, "dispatch", lambda chosen, depth, T_wc, scene, start, key, mesh, size, **kw: (
        seen.append(f"call {chosen}") or {"path": np.zeros((size, 1), np.int32)}))

    def chunk(order):
        S = len(order)
        return data.Chunk(scenes=[types.SimpleNamespace(table_height=0.0)] * S, intrinsics=None,
                          depth=np.zeros((S, 2, 3, 4), np.float32), T_wc=np.zeros((S, 2, 4, 4), np.float32))

    scenes = types.SimpleNamespace(loads_beside_renders=lambda: True, prepare_renderer=lambda: None, chunk=chunk)
    for who in (("a", "b"), ("b",)):  # (both classifiers' episodes; b's alone: the first call needs b)
        todo = [(c, row, s, 0) for c in who for row in config.rows for s in range(2)]
        seen.clear()
        b_loaded = Future()
        classifiers, loading = {"a": "A"}, {"a": []}

        def more(classifiers=classifiers, loading=loading, b_loaded=b_loaded):
            seen.append("more")
            classifiers["b"] = "B"
            loading["b"] = [b_loaded]
            threading.Timer(0.5, lambda: b_loaded.set_result(None) or seen.append("b's programs loaded")).start()

        made = runner.run_batched(config, scenes, DatasetConfig(), classifiers, None, todo,
                                  tmp_path / f"{len(who)}.jsonl", tqdm(disable=True), loading=loading, more=more)
        assert sorted(runner.record_key(r) for r in made) == sorted(todo)
        if who == ("a", "b"):  # (a's second program's call goes out while b loads)
            assert seen == ["call A", "more", "call A", "b's programs loaded", "call B", "call B"], seen
        else:
            assert seen == ["more", "b's programs loaded", "call B", "call B"], seen


def test_the_oracle_splits_its_calls_not_its_scenes():
    """The oracle's calls are the same for every process count (process i of N runs calls i, i + N, ...): each
    classifier's episodes in (scene, run) order, ``oracle_runs_per_call`` a call; a call's frames hold its scenes."""
    config = Table1Config(rows=("random_gr", "oracle_gr"), classifiers={"a": "", "b": ""}, runs=3, scenes=6,
                          oracle_scenes=5, oracle_runs_per_call=4, scene_chunk=3)
    keys = [k for k in runner.episode_keys(config, 6) if k[1] == "oracle_gr"]
    calls = runner.oracle_calls(config, keys)
    assert runner.oracle_call_size(config) == 4  # (every call padded to it, a resumed run's last one too)
    assert [len(call) for call in calls] == [4, 4, 4, 3] * 2 and sorted(k for c in calls for k in c) == sorted(keys)
    assert calls[1] == [("a", "oracle_gr", 1, 1), ("a", "oracle_gr", 1, 2), ("a", "oracle_gr", 2, 0),
                        ("a", "oracle_gr", 2, 1)]
    assert {k[0] for k in calls[4]} == {"b"} and max(k[2] for k in keys) == 4  # (the first oracle_scenes only)
    assert runner.oracle_frames(config, calls) == 3  # scene_chunk
    assert runner.oracle_frames(dataclasses.replace(config, scene_chunk=1), calls) == 2  # a call's scenes


def test_table_and_csv_against_hand_made_episodes():
    """Two scenes, one run each: VisOcclHistGR gets scene 0 all right after move 2 and one object wrong in
    scene 1; PointNetSingleGR (one move) gets one wrong in each scene. The pooled scores, the per-move CSV
    and the moves-to-correct are checked against classification_scores and hand counts."""
    records = [
        _record("vis_occl_hist_gr", 0, 0, [0, 1, 2], [[0, 2, 2], [0, 1, 2]]),
        _record("vis_occl_hist_gr", 1, 0, [1, 2, 3], [[1, 2, 0], [1, 2, 0]]),
        _record("single_gr", 0, 0, [0, 1, 2], [[0, 2, 2]]),
        _record("single_gr", 1, 0, [1, 2, 3], [[1, 2, -1]]),
    ]
    config = Table1Config(moves=2, runs=1, rows=("single_gr", "vis_occl_hist_gr"), classifiers={"c": ""},
                          resamples=100)
    markdown, rows, curves = tables.tables(config, records, 4, None, ["x"])
    policy = metrics.classification_scores(np.array([0, 1, 2, 1, 2, 3]), np.array([0, 1, 2, 1, 2, 0]), 4)
    single = metrics.classification_scores(np.array([0, 1, 2, 1, 2, 3]), np.array([0, 2, 2, 1, 2, -1]), 4)
    line = next(x for x in markdown.splitlines() if x.startswith("| VisOcclHistGR |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:5] == [f"{policy.accuracy:.3f}", f"{policy.precision:.3f}", f"{policy.recall:.3f}",
                          f"{policy.f1:.3f}"]
    # Moves to correct: scene 0's object 1 turns right at move 2, the others are right from move 1; scene 1's
    # object 3 never is: mean over the 5 right ones = (1 + 2 + 1 + 1 + 1) / 5; 5 of 6 right at the end.
    assert cells[7:9] == ["1.20", "0.83"]
    single_line = next(x for x in markdown.splitlines() if x.startswith("| PointNetSingleGR |"))
    assert f"| {single.f1:.3f} |" in single_line
    assert [(r["row"], r["move"]) for r in rows] == [("single_gr", 1), ("vis_occl_hist_gr", 1),
                                                     ("vis_occl_hist_gr", 2)]
    first = metrics.classification_scores(np.array([0, 1, 2, 1, 2, 3]), np.array([0, 2, 2, 1, 2, 0]), 4)
    assert rows[1]["f1"] == pytest.approx(first.f1) and rows[2]["f1"] == pytest.approx(policy.f1)
    assert rows[2]["f1_low"] <= rows[2]["f1"] <= rows[2]["f1_high"] and rows[2]["scenes"] == 2
    assert list(curves["c"]) == ["PointNetSingleGR", "VisOcclHistGR"]
    assert "VisOcclHistGR - PointNetSingleGR" in markdown  # the paired difference against one view
    assert cells[-2:] == ["-", "-"]  # (records without their phantom segments)
    # Phantom segments (live, matched to no object): after move 2 scene 0 has one labelled 1 and one labelled 3,
    # scene 1 none; 5 segments live against 5 objects in scene 0 (3 targets, 2 clutter), 4 against 5 in scene 1.
    records[0].update(phantom=[[], [1, 3]], segments=[4, 5], objects=5)
    records[1].update(phantom=[[2], []], segments=[5, 4], objects=5)
    for r in records[2:]:
        r.update(phantom=[[]], segments=[5], objects=5)
    markdown, _, _ = tables.tables(config, records, 4, None, ["x"])
    cells = [c.strip() for c in next(x for x in markdown.splitlines()
                                     if x.startswith("| VisOcclHistGR |")).strip("|").split("|")]
    # Each phantom a false positive of its class, the padded slots (-1, -1) nowhere.
    detected = metrics.classification_scores(np.array([0, 1, 2, -1, -1, 1, 2, 3, -1, -1]),
                                             np.array([0, 1, 2, 1, 3, 1, 2, 0, -1, -1]), 4)
    assert detected.f1 < policy.f1 and cells[-2].startswith(f"{detected.f1:.3f} [")
    assert cells[-1] == "-0.50 (abs 0.50)"


def test_the_learned_row_is_paired_with_the_best_hand_made_policy_and_the_oracle():
    """With a learned row, the tables pair it with the best hand-made policy by F1 at T (here InfoGainGR, right
    everywhere, not VisOcclHistGR) and the oracle with it; the differences are the pooled F1s'."""
    truth = {0: [0, 1, 2], 1: [1, 2, 3]}
    right = {0: [0, 1, 2], 1: [1, 2, 3]}
    wrong = {0: [0, 2, 2], 1: [1, 2, 0]}
    made = {"vis_occl_hist_gr": (right, wrong), "info_gain_gr": (right, right), "learned_gr": (wrong, wrong),
            "oracle_gr": (right, right)}
    records = [_record(row, s, 0, truth[s], [labels[s]] * 2) for row, (a, b) in made.items()
               for s, labels in ((0, a), (1, b))]
    config = Table1Config(moves=2, runs=1, oracle_scenes=2, rows=tuple(made), classifiers={"c": ""}, resamples=100,
                          nbv=nbv.NBVConfig(max_candidates=16, learned=nbv.Learned(weights="real_like")))
    markdown = tables.tables(config, records, 4, None, ["x"])[0]
    learned = metrics.classification_scores(np.array(truth[0] + truth[1]), np.array(wrong[0] + wrong[1]), 4).f1
    against = "The learned policy against the best hand-made one: LearnedGR - InfoGainGR"
    assert f"{against}: {learned - 1:+.3f} [" in markdown
    assert f"Oracle against the learned policy: OracleGR - LearnedGR: {1 - learned:+.3f} [" in markdown
    # The share of the oracle's lead the learned policy closes: none to close here (the oracle ties InfoGainGR).
    assert ("The share of the oracle's lead the learned policy closes: (LearnedGR - InfoGainGR) / (OracleGR - "
            "InfoGainGR) on the 2 scenes of all three: +inf [+inf, +inf] (+inf: the oracle does not lead InfoGainGR "
            "there)") in markdown
    # A learned policy between the best hand-made one and the rollout oracle, and the best policy: its share is the
    # ratio of the pooled F1s; the oracle is paired with it once (as the best policy).
    truth = {s: [0, 1, 2, 3] for s in range(3)}
    labels = {"info_gain_gr": [[0, 1, 0, 0], [0, 0, 2, 0], [0, 1, 2, 0]],
              "learned_gr": [[0, 1, 2, 0], [0, 1, 2, 0], [0, 1, 2, 0]],
              "oracle_rollout_gr": [[0, 1, 2, 3], [0, 1, 2, 3], [0, 1, 2, 3]]}
    records = [_record(row, s, 0, truth[s], [per_scene[s]] * 2) for row, per_scene in labels.items() for s in range(3)]
    config = dataclasses.replace(config, rows=tuple(labels), oracle_scenes=3)
    markdown = tables.tables(config, records, 4, None, ["x"])[0]

    def f1(row):
        return metrics.classification_scores(np.concatenate(list(truth.values())), np.concatenate(labels[row]), 4).f1

    share = (f1("learned_gr") - f1("info_gain_gr")) / (f1("oracle_rollout_gr") - f1("info_gain_gr"))
    assert 0 < share < 1
    assert ("The share of the oracle's lead the learned policy closes: (LearnedGR - InfoGainGR) / (OracleRolloutGR - "
            f"InfoGainGR) on the 3 scenes of all three: {share:+.2f} [") in markdown
    assert "does not lead" not in markdown
    assert "Oracle against the best policy: OracleRolloutGR - LearnedGR" in markdown
    assert "Oracle against the learned policy" not in markdown
    assert "The same share with the learned policy's lead" not in markdown  # (the oracle on every scene)
    # The oracle on scenes 0 and 2 of 4: the share paired there, and with the learned policy's lead on all 4 (its
    # interval a bootstrap stratified by those scenes: the same as the metric's with that mask).
    truth = {s: [0, 1, 2, 3] for s in range(4)}
    labels = {"info_gain_gr": [[0, 1, 0, 0], [0, 0, 2, 0], [0, 1, 2, 0], [0, 0, 0, 0]],
              "learned_gr": [[0, 1, 2, 0], [0, 1, 2, 0], [0, 1, 2, 3], [0, 0, 0, 3]],
              "oracle_rollout_gr": [[0, 1, 2, 3], None, [0, 1, 2, 3], None]}
    records = [_record(row, s, 0, truth[s], [per_scene[s]] * 2) for row, per_scene in labels.items() for s in range(4)
               if per_scene[s] is not None]
    markdown = tables.tables(config, records, 4, None, ["x"])[0]

    def on(row, scenes):
        return [(np.array(truth[s]), np.array(labels[row][s])) for s in scenes]

    there = metrics.share_of_gap(*(on(n, [0, 2]) for n in ("learned_gr", "info_gain_gr", "oracle_rollout_gr")), 4,
                                 resamples=100)
    wide = metrics.share_of_gap_all_scenes(on("learned_gr", range(4)), on("info_gain_gr", range(4)),
                                           on("oracle_rollout_gr", [0, 2]), on("info_gain_gr", [0, 2]),
                                           np.array([True, False, True, False]), 4, resamples=100)
    assert wide[0] != there[0] and wide[1:] != (wide[0], wide[0])

    def shown(x):
        return "{} [{}, {}]".format(*map(format_share, x))

    assert f"InfoGainGR) on the 2 scenes of all three: {shown(there)}" in markdown
    assert ("The same share with the learned policy's lead over InfoGainGR on all 4 scenes, the oracle's on its 2 "
            f"(metrics.share_of_gap_all_scenes): {shown(wide)}") in markdown


def test_tables_only_reads_the_archived_episodes_and_refuses_a_folder_without_any(table1, tmp_path, capsys):
    """``--tables-only`` on a results folder, which keeps its episodes as ``episodes.jsonl.xz``: the tables of
    those; on a folder with no episodes of the config, a clear error, and no table written over the one there."""
    import lzma

    out = tmp_path / "run"
    out.mkdir()
    config = tmp_path / "table1.yaml"
    config.write_text(f"out_dir: {out}\ndataset: synthetic\nruns: 1\nmoves: 2\nrows: [vis_occl_hist_gr]\n"
                      "classifiers: {c: ''}\nresamples: 100\n")
    (out / "table.md").write_text("kept")
    with pytest.raises(SystemExit):
        table1.main(["--config", str(config), "--tables-only"])
    assert "no episodes of this config's rows and classifiers" in capsys.readouterr().err
    assert (out / "table.md").read_text() == "kept"
    records = [_record("vis_occl_hist_gr", s, 0, [0, 1, 2], [[0, 1, 2], [0, 1, 1]]) for s in (0, 1, 2)]
    for name, part in (("episodes.jsonl.xz", records[:2]), ("episodes.1.jsonl.xz", records[2:])):  # (a process's)
        with lzma.open(out / name, "wt") as f:
            f.writelines(json.dumps(r) + "\n" for r in part)
    table1.main(["--config", str(config), "--tables-only"])
    line = next(x for x in (out / "table.md").read_text().splitlines() if x.startswith("| VisOcclHistGR |"))
    want = metrics.classification_scores(np.array([0, 1, 2] * 3), np.array([0, 1, 1] * 3), 4)
    assert f"| {want.f1:.3f} |" in line and "| 3 | 3 |" in line and not (out / "episodes.jsonl").exists()
    # Archived episodes of another config are refused as stored ones are.
    save_config(load_config(Table1Config, config), out / "config.yaml")
    with pytest.raises(ValueError, match=r"out_dir holds episodes of another config \(keys \['seed'\] differ"):
        table1.main(["--config", str(config), "--tables-only", "seed=5"])


def test_rows_tabulated_while_the_oracle_runs_are_those_tabulated_at_the_end():
    """--local-processes' launcher tabulates the batched rows once all their episodes are stored, while the
    processes still run the oracle (``tables.EarlyRows``): the tables equal those made at the end; a summary is
    used only where made of the same episodes in the same order."""
    config = Table1Config(moves=2, runs=1, scenes=2, oracle_scenes=2, rows=("single_gr", "vis_occl_hist_gr",
                          "oracle_gr"), classifiers={"c": ""}, resamples=100)
    batched = [_record("vis_occl_hist_gr", 0, 0, [0, 1, 2], [[0, 2, 2], [0, 1, 2]]),
               _record("single_gr", 0, 0, [0, 1, 2], [[0, 2, 2]]),
               _record("vis_occl_hist_gr", 1, 0, [1, 2, 3], [[1, 2, 0], [1, 2, 0]]),
               _record("single_gr", 1, 0, [1, 2, 3], [[1, 2, -1]])]
    oracle = [_record("oracle_gr", 0, 0, [0, 1, 2], [[0, 2, 2], [0, 1, 2]]),
              _record("oracle_gr", 1, 0, [1, 2, 3], [[1, 2, 0], [1, 2, 3]])]
    early = tables.EarlyRows(config, 4, runner.episode_keys(config, 2))
    early.offer(batched[:3] + oracle)  # (a batched episode still missing)
    assert early.result() == tables.Early({}, {})
    early.offer(batched + oracle[:1])
    made = early.result()
    assert set(made.summaries) == {("c", "single_gr"), ("c", "vis_occl_hist_gr")}
    # The batched rows' difference made early (VisOcclHistGR - PointNetSingleGR), not the oracle's (it waits).
    assert [k[1:3] for k in made.differences] == [("vis_occl_hist_gr", "single_gr")]
    records = batched + oracle
    assert tables.tables(config, records, 4, None, ["x"], made) == tables.tables(config, records, 4, None, ["x"])
    marked = tables.Early(
        {k: dataclasses.replace(v, cells=(f"made early: {v.cells[0]}", *v.cells[1:]))
         for k, v in made.summaries.items()},
        {k: (0.5, 0.25, 0.75) for k in made.differences})  # (a difference no bootstrap of these records gives)
    markdown = tables.tables(config, records, 4, None, ["x"], marked)[0]
    assert "| made early: VisOcclHistGR |" in markdown and "| made early: PointNetSingleGR |" in markdown
    assert "VisOcclHistGR - PointNetSingleGR: +0.500 [+0.250, +0.750]" in markdown
    policy_swapped = [batched[2], batched[1], batched[0], batched[3]]  # (VisOcclHistGR's scenes in another order)
    markdown = tables.tables(config, policy_swapped + oracle, 4, None, ["x"], marked)[0]
    assert "| VisOcclHistGR |" in markdown and "| made early: PointNetSingleGR |" in markdown
    assert "+0.500 [+0.250, +0.750]" not in markdown  # (a row made again: its differences made again too)


def test_protocol_rows_and_starts():
    assert protocol.PAPER_ROWS == ("single", "single_gr", "full", "full_gr", "random", "random_gr", "vis_no_occl",
                                   "vis_no_occl_gr", "vis_occl", "vis_occl_gr", "vis_occl_hist", "vis_occl_hist_gr")
    np.testing.assert_array_equal(protocol.start_views(0, 3, 10, 100), protocol.start_views(0, 3, 10, 100))
    assert len(set(protocol.start_views(0, 3, 10, 100).tolist())) == 10
    with pytest.raises(ValueError, match="rows: unknown row 'vis_oops'"):
        protocol.row("vis_oops")
    from jaxcls.episode.setup import ActiveConfig

    settings = protocol.ROWS["single_gr"].settings(ActiveConfig(), 10)
    assert settings.episode.moves == 1 and settings.episode.refinement
    settings = protocol.ROWS["vis_occl_hist_gr_category"].settings(ActiveConfig(), 10)
    assert settings.episode.moves == 10 and settings.refine.library == "category"


def test_bad_inputs_are_refused_naming_the_key_or_file(tmp_path):
    with pytest.raises(ConfigError, match="unknown row 'vis_oops'"):
        load_config(Table1Config, "table1_synthetic", ["rows=[vis_oops]"])
    with pytest.raises(ValueError, match="neither a dataset folder nor a dataset config"):
        data.open_dataset(Table1Config(dataset=str(tmp_path / "nothing"), classifiers={"c": ""}))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match=r"no config\.yaml"):
        data.open_dataset(Table1Config(dataset=str(empty), classifiers={"c": ""}))
    # A dataset folder whose scenes were drawn from another object set than its config says.
    from jaxcls.world.dataset import DatasetConfig

    folder = tmp_path / "data"
    argv = _small(tmp_path, "c")
    config = load_config(Table1Config, argv[1], argv[2:])
    dataset, files = data.open_dataset(config)
    other = tmp_path / "other"
    other.mkdir()
    (other / "scene_000.npz").write_bytes(files[0].read_bytes())
    save_config(dataclasses.replace(dataset, objects=dataclasses.replace(dataset.objects, seed=1)),
                other / "config.yaml")
    bad = dataclasses.replace(config, dataset=str(other), dataset_overrides=())
    with pytest.raises(ValueError, match=r"scene_000\.npz: the scene was drawn from objects"):
        runner.run_episodes(bad, data.Scenes.from_files(data.dataset_config(bad), [other / "scene_000.npz"]),
                            data.dataset_config(bad), tmp_path / "x.jsonl", show_progress=False)
    assert not (tmp_path / "x.jsonl").exists()
    assert isinstance(dataset, DatasetConfig) and folder.is_dir()
    # A classifier trained on other classes.
    from jaxcls.perception import pointnet

    weights = tmp_path / "w.msgpack"
    shipped = pointnet.load_classifier()
    pointnet.save_classifier(weights, dataclasses.replace(shipped, classes=tuple(f"c{i}" for i in shipped.classes)))
    with pytest.raises(ValueError, match=r"w.msgpack \(classifiers.mine\).*trained on classes"):
        runner.run_episodes(dataclasses.replace(config, classifiers={"mine": str(weights)}),
                            data.Scenes.from_files(dataset, files), dataset, tmp_path / "y.jsonl", show_progress=False)
    assert not (tmp_path / "y.jsonl").exists()


def test_fused_views_subsets_and_pose_errors():
    """jaxcls.experiments.fused_views: seeded distinct view subsets (every view, in order, when k >= V); a
    frame's pose error as the displacement of the scene's centre, its rotation and the spread about the
    frames' mean error (a common offset blurs nothing)."""
    from jaxcls.experiments import fused_views

    chosen = fused_views.subset(0, 3, 4, 1, 12)
    assert len(set(chosen.tolist())) == 4 and chosen.min() >= 0 and chosen.max() < 12
    np.testing.assert_array_equal(chosen, fused_views.subset(0, 3, 4, 1, 12))
    assert not np.array_equal(chosen, fused_views.subset(0, 3, 4, 2, 12))
    np.testing.assert_array_equal(fused_views.subset(0, 3, 20, 0, 12), np.arange(12))
    true = np.tile(np.eye(4), (3, 1, 1))
    true[:, :3, 3] = [[0.5, 0, 1], [0, 0.5, 1], [-0.5, 0, 1]]
    shifted = true.copy()
    shifted[:, 0, 3] += 0.002  # every frame 2 mm off along x: the model moves, nothing blurs
    errors = fused_views.pose_errors(shifted, true, table_height=0.1)
    np.testing.assert_allclose(errors["translation_mm"], 2.0, atol=1e-6)
    np.testing.assert_allclose(errors["relative_mm"], 0.0, atol=1e-6)
    np.testing.assert_allclose(errors["rotation_deg"], 0.0, atol=1e-6)


def test_records_of_a_batch_are_each_episodes_own():
    """``protocol.episode_records`` over E episodes gives each episode's ``episode_record``; a stopped episode
    keeps its last labels and lists only the moves it made."""
    from jaxcls.episode import active, scoring

    rng = np.random.default_rng(0)
    E, T, N, K = 3, 4, 6, 4
    done = np.zeros((E, T), bool)
    done[1, 2:] = True
    hand_eye = np.tile(np.eye(4, dtype=np.float32), (E, T, 1, 1))
    hand_eye[..., :3, 3] = rng.normal(0, 0.01, (E, T, 3))
    refinement = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (E, T, *x.shape)).copy(),
                              active.empty_refinement(N, 3))
    refinement = refinement.replace(prior=rng.integers(0, 5, (E, T, N)), refined=rng.integers(0, 5, (E, T, N)),
                                    valid=rng.random((E, T, N)) < 0.8)
    traces = active.Trace(view=rng.integers(0, 30, (E, T)), refinement=refinement, probs=np.zeros((E, T, N, 5)),
                          centroid=rng.normal(0, 0.1, (E, T, N, 3)), points=np.zeros((E, T, N), np.int32),
                          next_view=np.zeros((E, T), np.int32), tracking=rng.integers(0, 3, (E, T)).astype(np.int32),
                          pose=hand_eye.copy(), hand_eye=hand_eye, done=done)
    truths = [scoring.Truth(centroid=rng.normal(0, 0.1, (K, 3)), label=rng.integers(0, 5, K),
                            target=np.arange(K) < 3, surface=(), names=()) for _ in range(E)]
    together = protocol.episode_records(traces, truths, [{"run": e} for e in range(E)])
    for e in range(E):
        assert together[e] == protocol.episode_record(jax.tree.map(lambda x, e=e: x[e], traces), truths[e], run=e)
    stopped = together[1]
    assert len(stopped["path"]) == len(stopped["hand_eye"]) == 2 and stopped["refined"][3] == stopped["refined"][1]
    assert stopped["phantom"][3] == stopped["phantom"][1] and stopped["segments"][3] == stopped["segments"][1]
    for e in range(E):  # phantoms: the live segments no object (target or clutter) took, with their refined class
        for t in range(T if e != 1 else 2):
            match = set(metrics.match_objects(traces.centroid[e, t], refinement.valid[e, t], truths[e].centroid))
            live = np.flatnonzero(refinement.valid[e, t])
            assert together[e]["phantom"][t] == [int(refinement.refined[e, t, n]) for n in live if n not in match]
            assert together[e]["segments"][t] == len(live) and together[e]["objects"] == K
    assert any(together[e]["phantom"][t] for e in range(E) for t in range(T))  # (some phantoms to check)
    assert np.allclose(np.asarray(together[0]["hand_eye"])[:, :3], hand_eye[0, :, :3, 3], atol=1e-5)


def test_a_chunk_is_dealt_round_robin_over_the_devices_and_padded_per_device():
    cases = [(250, 1, 100, 0, 10), (1000, 4, 100, 0, 10), (7, 3, 4, 0, 2), (250, 1, 100, 400, 10),
             (1000, 2, 400, 3000, 10), (1, 4, 8, 0, 10), (13, 2, 100, 30, 5)]
    for scenes, devices, scene_chunk, batch, runs in cases:  # (scenes, devices, scene_chunk, batch_episodes, runs)
        per, per_call = runner.chunk_sizes(scenes, devices, scene_chunk, batch, runs)
        chunks, calls = -(-scenes // (devices * per)), -(-per // per_call)
        assert devices * per <= -(-scene_chunk // devices) * devices  # a chunk within scene_chunk (rounded up)
        assert not batch or per_call * devices * runs <= max(batch, devices * runs)  # a call within batch_episodes
        assert chunks * devices * per - scenes < chunks * devices  # padded by less than a scene a device a chunk
        assert calls * per_call - per < calls  # and a call by less than a scene a device
    assert runner.chunk_sizes(250, 1, 100, 0, 10) == (84, 84) and runner.chunk_sizes(1000, 4, 100, 0, 10) == (25, 25)
    assert runner.chunk_sizes(250, 1, 100, 400, 10) == (84, 28)  # 3 calls of 28 scenes, not 40, 40 and 4
    assert runner.chunk_layout([10, 11, 12, 13, 14, 15, 16], 3, 3) == [10, 13, 16, 11, 14, 11, 12, 15, 12]
    assert runner.chunk_layout([4, 5], 1, 3) == [4, 5, 4]  # one device: the chunk, its last slots padded
    assert runner.chunk_layout([7], 2, 1) == [7, 7]  # a device with no scene repeats the chunk's first
    with pytest.raises(ValueError, match="do not fit 2 x 1 slots"):
        runner.chunk_layout([1, 2, 3], 2, 1)
    # Calls of 2 slots a device over 3 devices x 3 slots: every scene in one call, from the slot that holds it,
    # at most 2 a device; the padding slots (11, 12 repeated) run nothing.
    slots = runner.chunk_layout([10, 11, 12, 13, 14, 15, 16], 3, 3)
    groups = runner.call_scenes(slots, 3, 2)
    assert groups == [{10, 13, 11, 14, 12, 15}, {16}]
    assert runner.call_scenes(runner.chunk_layout(list(range(8)), 2, 4), 2, 4) == [set(range(8))]


def test_oracle_moves_gives_each_rows_f1_per_move_and_last_move_gain_on_the_oracles_scenes():
    """``experiments/oracle_moves.py``: every row's pooled F1 after each move on the scenes the oracle ran (not the
    policy's others), and its last-move gain paired by scene."""
    spec = importlib.util.spec_from_file_location("oracle_moves", ROOT / "experiments" / "oracle_moves.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    truth = [0, 1, 2, 3]
    wrong, right = [0, 1, 0, 0], [0, 1, 2, 3]
    records = [_record("info_gain_gr", s, 0, truth, [wrong, wrong]) for s in range(3)]  # (scene 2: no oracle)
    records += [_record("oracle_gr", s, 0, truth, [wrong, right]) for s in range(2)]
    config = Table1Config(moves=2, runs=1, oracle_scenes=2, rows=("info_gain_gr", "oracle_gr"), classifiers={"c": ""},
                          resamples=100)
    text = module.tables(config, records, 4)
    f1 = [metrics.classification_scores(np.array(truth * 2), np.array(labels * 2), 4).f1 for labels in (wrong, right)]
    assert "#### Classifier `c`: 2 scenes" in text
    assert f"| InfoGainGR | {f1[0]:.3f} | {f1[0]:.3f} | +0.000 [+0.000, +0.000] |" in text
    assert f"| OracleGR | {f1[0]:.3f} | {f1[1]:.3f} | {f1[1] - f1[0]:+.3f} [" in text


def test_compare_runs_pairs_a_row_of_two_runs_episode_by_episode_after_checking_that_they_drew_the_same_scenes():
    """``experiments/compare_runs.py``: B's row - A's on the (scene, run) episodes both hold, the share of each run's
    oracle lead for both; runs whose reference row differs in any episode, or share none, are refused by name."""
    spec = importlib.util.spec_from_file_location("compare_runs", ROOT / "experiments" / "compare_runs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    truth, wrong, half, right = [0, 1, 2, 3], [0, 1, 0, 0], [0, 1, 2, 0], [0, 1, 2, 3]
    base = [_record("info_gain_gr", s, 0, truth, [wrong]) for s in range(3)]
    a = base + [_record("learned_gr", s, 0, truth, [wrong]) for s in range(3)]
    a += [_record("learned_gr", 0, 1, truth, [right])]  # (a run B lacks: left out of the pairs)
    a += [_record("oracle_gr", s, 0, truth, [right]) for s in range(2)]
    b = base + [_record("learned_gr", s, 0, truth, [half if s < 2 else right]) for s in range(3)]
    b += [_record("oracle_gr", 0, 0, truth, [right])]  # (B's oracle on one scene: no interval)
    text = module.tables(a, b, ["c"], "learned_gr", "info_gain_gr", 4, 1, resamples=100)
    f1 = [metrics.classification_scores(np.array(truth * 3), np.array(x * 3), 4).f1 for x in (wrong, half, right)]
    b_f1 = metrics.classification_scores(np.array(truth * 3), np.array(half * 2 + right), 4).f1
    assert "- InfoGainGR: the same start, path and labels in all 3 episodes both runs hold." in text
    assert f"- LearnedGR: B - A on 3 episodes of 3 scenes: {b_f1 - f1[0]:+.3f} [" in text
    assert f"- LearnedGR - InfoGainGR there: A +0.000 [+0.000, +0.000], B {b_f1 - f1[0]:+.3f} [" in text
    # The shares on A's oracle's 2 scenes (B's lead there: half's), and with the leads on all 3 (scene 2: right).
    share, everywhere = (f1[1] - f1[0]) / (f1[2] - f1[0]), (b_f1 - f1[0]) / (f1[2] - f1[0])
    assert f"| OracleGR (A: 2, 2) | {f1[2] - f1[0]:+.3f} [" in text
    assert f"| +0.00 [+0.00, +0.00] | {share:+.2f} [" in text and share != everywhere
    assert f"| {f1[1] - f1[0]:+.3f} [" in text and f"| +0.00 [+0.00, +0.00] | {everywhere:+.2f} [" in text
    assert "its lead on all 3 scenes" in text
    # The oracle on scenes 0 and 2 of 4 (not a prefix; 2 others to draw): B's all-scenes share is the metric's
    # with that mask, interval included.
    four = {"info_gain_gr": [wrong, half, wrong, wrong], "learned_gr": [half, half, right, wrong],
            "oracle_gr": [right, None, right, None]}
    a4 = [_record(row, s, 0, truth, [x]) for row, xs in four.items() for s, x in enumerate(xs) if x is not None]
    b4 = [dict(r) for r in a4 if r["row"] != "oracle_gr"]
    text4 = module.tables(a4, b4, ["c"], "learned_gr", "info_gain_gr", 4, 1, resamples=100)

    def on(row, scenes):
        return [(np.array(truth), np.array(four[row][s])) for s in scenes]

    wide = metrics.share_of_gap_all_scenes(on("learned_gr", range(4)), on("info_gain_gr", range(4)),
                                           on("oracle_gr", [0, 2]), on("info_gain_gr", [0, 2]),
                                           np.array([True, False, True, False]), 4, resamples=100)
    assert wide[1] < wide[2] and text4.rstrip().endswith("| {} [{}, {}] |".format(*map(format_share, wide)))
    assert "| OracleGR (B: 1, 1) | fewer than 2 scenes in common: no interval |" in text
    other = [dict(r, path=[5]) if r["row"] == "info_gain_gr" and r["scene"] == 1 else r for r in b]
    with pytest.raises(ValueError, match=r"info_gain_gr episode \(scene 1, run 0\) has another path"):
        module.tables(a, other, ["c"], "learned_gr", "info_gain_gr", 4, 1, resamples=100)
    with pytest.raises(ValueError, match="share no vis_occl_gr episode"):
        module.tables(a, b, ["c"], "learned_gr", "vis_occl_gr", 4, 1, resamples=100)


def test_compare_runs_pools_pairs_on_different_draws_as_one_run_and_refuses_a_draw_given_twice(tmp_path, capsys):
    """``compare_runs.py --a A1 --b B1 --a A2 --b B2``: the tables of one run on both draws' scenes (pair 2's
    numbered after the last scene of either run of pair 1), each pair checked on its own; two pairs of one
    dataset seed (even with other Table 1 seeds), or unpaired runs, are refused."""
    spec = importlib.util.spec_from_file_location("compare_runs", ROOT / "experiments" / "compare_runs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    truth, wrong, half, right = [0, 1, 2, 3], [0, 1, 0, 0], [0, 1, 2, 0], [0, 1, 2, 3]
    labels = {  # per draw: each row's labels on scenes 0-2 (the oracle on the first 2)
        1: {"info_gain_gr": [wrong, wrong, half], "learned_gr": [half, wrong, half], "oracle_gr": [right, right]},
        2: {"info_gain_gr": [half, wrong, wrong], "learned_gr": [right, half, wrong], "oracle_gr": [right, half]}}
    policy_b = {1: [half, half, right], 2: [right, right, half]}

    def records(draw, run):
        out = [_record(row, s, 0, truth, [x]) for row, xs in labels[draw].items() for s, x in enumerate(xs)]
        if run == "b":
            out = [r for r in out if r["row"] != "learned_gr" and r["row"] != "oracle_gr"]
            out += [_record("learned_gr", s, 0, truth, [x]) for s, x in enumerate(policy_b[draw])]
        elif draw == 1:  # (a scene of A's alone, left out of the pairs: pair 2 is numbered after it)
            out += [_record(row, 3, 0, truth, [right]) for row in ("info_gain_gr", "learned_gr")]
        return out

    def store(draw, run, edit=lambda r: r, seed=0):
        folder = tmp_path / f"{run}{draw}_{seed}"
        folder.mkdir(exist_ok=True)
        (folder / "episodes.jsonl").write_text("".join(json.dumps(edit(r)) + "\n" for r in records(draw, run)))
        config = Table1Config(out_dir=str(folder), dataset_overrides=(f"seed={draw}",), seed=seed, moves=1, runs=1,
                              rows=("info_gain_gr", "learned_gr", "oracle_gr"), oracle_scenes=2,
                              classifiers={"c": ""}, learned_weights={"c": "real_like_paper"}, resamples=100)
        save_config(config, folder / "config.yaml")
        return str(folder / "config.yaml")

    a1, b1, a2, b2 = store(1, "a"), store(1, "b"), store(2, "a"), store(2, "b")
    out = tmp_path / "pooled.md"
    module.main(["--a", a1, "--b", b1, "--a", a2, "--b", b2, "--out", str(out)])
    text = out.read_text()

    def shifted(draw, run):
        return [dict(r, scene=r["scene"] + 4 * (draw - 1)) for r in records(draw, run)]

    expected = module.tables(shifted(1, "a") + shifted(2, "a"), shifted(1, "b") + shifted(2, "b"), ["c"],
                             "learned_gr", "info_gain_gr", 8, 1, resamples=100)
    assert text.rstrip().endswith(expected.rstrip())
    assert "Pooled: 2 pairs, each its own draw of scenes (dataset seeds 1, 2)" in text
    assert "The A runs differ in: dataset_overrides." in text
    f1 = [metrics.classification_scores(np.array(truth * 6), np.concatenate(rows), 8).f1
          for rows in (labels[1]["learned_gr"] + labels[2]["learned_gr"], policy_b[1] + policy_b[2])]
    assert f"- LearnedGR: B - A on 6 episodes of 6 scenes: {f1[1] - f1[0]:+.3f} [" in text
    base = metrics.classification_scores(np.array(truth * 6), np.concatenate(
        labels[1]["info_gain_gr"] + labels[2]["info_gain_gr"]), 8).f1
    assert f"- LearnedGR - InfoGainGR there: A {f1[0] - base:+.3f} [" in text and f", B {f1[1] - base:+.3f} [" in text
    assert "| OracleGR (A: 4, 4) |" in text  # (both draws' oracle scenes)
    with pytest.raises(SystemExit):
        module.main(["--a", a1, "--b", b1, "--a", a1, "--b", b2])
    assert "draws the same scenes as" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # (another Table 1 seed: other starts on the same scenes)
        module.main(["--a", a1, "--b", b1, "--a", store(1, "a", seed=1), "--b", store(1, "b", seed=1)])
    assert "(dataset seed 1): pooled, they would count twice" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        module.main(["--a", a1, "--b", b1, "--a", a2])
    assert "give them in pairs" in capsys.readouterr().err
    b2_other = store(2, "b", lambda r: dict(r, path=[7]) if r["row"] == "info_gain_gr" and r["scene"] == 1 else r)
    with pytest.raises(SystemExit):
        module.main(["--a", a1, "--b", b1, "--a", a2, "--b", b2_other])
    assert f"{a2} and {b2_other}: classifier 'c': info_gain_gr episode (scene 1, run 0) has another path" in \
        capsys.readouterr().err
