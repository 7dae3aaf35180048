"""Table 1's episodes: every (classifier, row, scene, run) not yet stored, streamed to JSONL as each batch of
a row finishes (an interrupted run resumes without redoing or losing an episode); one episode timed module by
module. The single-view and policy rows run batched over scenes and runs in one switched program per
classifier (``episode.batched``); the oracle in calls of several scenes' runs; PointNetFull scene by scene."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import operator
import sys
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaxcls import compile_cache, devices, io, report
from jaxcls.episode import active, batched, protocol, runner, scoring, setup, sources
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.data import Chunk, Scenes, process_store, read_stores, record_key
from jaxcls.geometry import Intrinsics
from jaxcls.perception import pointnet
from jaxcls.planning import nbv
from jaxcls.world.dataset import DatasetConfig
from jaxcls.world.objects import object_set_from_config

# Linux caps a process's memory maps (vm.max_map_count, 65530 by default). On XLA's CPU backend each compiled
# row program holds ~1,600-2,400 of them (its JIT-compiled code), so a process that kept every row's program
# died with LLVM's "Cannot allocate memory" after ~30. On the CPU the rows run in passes over the scenes of at
# most this many (classifier, row) programs each, freed after the pass (a scene is read once per pass).
CPU_PROGRAMS_PER_PASS = 12
# Whether a run makes the batched rows' first chunk of frames on a thread while it loads its classifiers (where
# the renderer allows work beside its renders: ``Scenes.chunk_ahead``); False: after them, on the main thread;
# None: where a device renders them (``Scenes.on_device``). A warm run's first call on one H100 came 2.0 s
# sooner (21.2 -> 19.2 s after the process started); on the 2-core CPU, MuJoCo's C caster beside the loads,
# 0.4 s later (4.4 -> 4.8 s) (BENCHMARKS.md, "Table 1's warm start").
FRAMES_AHEAD: bool | None = None
# The phase of the first batched call (tracing, compiling or loading its program, and the call).
FIRST_CALL = "batched episodes, first call (compiles)"
# ``Phases.mark``'s name for the first batched call handed to the devices (a warm run's start: its time since
# the process started).
FIRST_CALL_DISPATCHED = "first batched call dispatched"
# The other marks of a run's start (``Phases.mark``; ``run_times.json``'s ``marks_s``), in the order they come on a
# warm GPU run: where the seconds before FIRST_CALL_DISPATCHED go (``benchmarks/first_call.py`` tabulates them).
DEVICES_READY = "devices ready"  # (experiments/table1.py: the accelerator's runtime started)
CLASSIFIERS_LOADED = "first classifier loaded"  # (the first call's; every one where ``LATER_CLASSIFIERS`` is off)
FIRST_FRAMES_MADE = "first frames made"  # (the batched rows' first chunk, where it is made ahead)
PROGRAMS_LOADED = "its batched programs loaded"  # (where loaded ahead from the cache)
# Whether a run with batched rows loads only the classifier of its first call before that call, and the others
# (each with its programs, ``load_batched_ahead``) once the call is on the devices, where the renderer allows a
# load beside its renders; False: every classifier before the first call. The host's work before the first call
# is Python under one lock (imports, classifiers, the first frames), so each classifier left out of it starts the
# run sooner (BENCHMARKS.md, "Table 1's warm start").
LATER_CLASSIFIERS = True
# The oracle's episodes in one call off the CPU: each tries its 32 candidates at every move, ~18,500 moves a call.
ORACLE_EPISODES_PER_CALL = 64


class Phases:
    """Wall seconds spent in each phase of a run (``clock(name)``: a context that adds to ``seconds[name]``)
    and the episodes it ran (``episodes``)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.episodes = 0
        self.marks: dict[str, float] = {}  # an event's time since the process started (s), ``mark``

    def mark(self, name: str) -> None:
        """Note when ``name`` first happened: the process's age (``report.process_age``; nothing where that is
        unknown; in a notebook, the kernel's), e.g. the first batched call dispatched: how long a warm run takes to
        start its episodes."""
        if name not in self.marks and (age := report.process_age()) is not None:
            self.marks[name] = age

    @contextlib.contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0


def write_run_times(path: Path, clock: Phases, total: float, device: str | None = None) -> None:
    """Append this run's phases (wall s) to ``path`` (a JSON list, one entry a run) and print them; ``total``:
    the wall seconds they are part of (what no phase names is the rest); ``device``: where the episodes ran
    (default this process's devices)."""
    runs = json.loads(path.read_text()) if path.exists() else []
    entry = {"device": device or report.device_name(), "devices": len(jax.local_devices()), "episodes": clock.episodes,
             "total_s": round(total, 1), "phases_s": {k: round(v, 1) for k, v in clock.seconds.items()}}
    if clock.marks:
        entry["marks_s"] = {k: round(v, 1) for k, v in clock.marks.items()}
    io.write_json(path, [*runs, entry])
    print(f"run times ({entry['device']}, {clock.episodes} episodes): {entry['total_s']} s; "
          + ", ".join(f"{k} {v} s" for k, v in entry["phases_s"].items())
          + "".join(f"; {k} at {v} s" for k, v in entry.get("marks_s", {}).items()), file=sys.stderr)


def run_times_file(store: Path, process: tuple[int, int]) -> Path:
    """Where a process's phases go (``write_run_times``): ``run_times.json`` beside the store, one a process."""
    return process_store(store.parent / "run_times.json", process)


def runs_of(row: protocol.Row, runs: int) -> int:
    """Episodes per scene of ``row``: one for PointNetFull (it has no start view), else ``runs``."""
    return 1 if row.kind is protocol.Kind.FULL else runs


def passes(programs: list, platform: str) -> list[list]:
    """``programs`` in the groups that run together: all at once off the CPU, ``CPU_PROGRAMS_PER_PASS`` on it."""
    size = CPU_PROGRAMS_PER_PASS if platform == "cpu" else max(1, len(programs))
    return [programs[i:i + size] for i in range(0, len(programs), size)]


BATCHED = (protocol.Kind.SINGLE, protocol.Kind.POLICY)  # rows run by the batched, switched program


def process_share() -> tuple[int, int]:
    """(this process's index, the process count): one process unless ``jax.distributed`` was initialised."""
    return jax.process_index(), jax.process_count()


def run_episodes(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig, store: Path,
                 show_progress: bool = True, process: tuple[int, int] | None = None,
                 clock: Phases | None = None) -> list[dict[str, Any]]:
    """Every (classifier, row, scene, run) episode not yet stored, appended to ``store`` (JSONL) as each batch
    of a row finishes; returns the records of this config's rows and scenes stored when it began (every
    process's) and those it added (with one process: all of them). The single-view and policy
    rows run batched over scenes and runs (``run_batched``), the oracle's runs of several scenes a call
    (``run_oracle``), PointNetFull scene by scene.

    Several processes (``process``: (index, count), default ``process_share()``; hosts of a ``jax.distributed``
    run) split the scenes: process i runs the scenes s with s % count == i (the oracle: its calls i, i + count,
    ..., ``oracle_calls``) on its local devices and appends to its own store (``data.process_store``); what is
    done is read from every process's store, so a run resumes under another process count too.

    ``clock``: where the phases' wall seconds go (the caller writes them); without one, the phases of a run
    that ran episodes are written to ``run_times.json`` beside the store (``run_times.<i>.json``)."""
    index, count = process or process_share()
    owner, began = clock is None, time.perf_counter()
    clock = clock or Phases()
    with clock("start-up (classifiers, stored episodes)"):
        stored = read_stores(store)
        rows = {name: protocol.row(name) for name in config.rows}
        done = {record_key(r) for r in stored}
        every = episode_keys(config, scene_set.count)
        oracle = oracle_calls(config, [k for k in every if rows[k[1]].kind is protocol.Kind.ORACLE])
        wanted = [k for k in every if k[2] % count == index and rows[k[1]].kind is not protocol.Kind.ORACLE]
        wanted += [k for call in oracle[index::count] for k in call]  # (the oracle's calls, not its scenes, split)
        todo = [k for k in wanted if k not in done]
        batched_todo = [k for k in todo if rows[k[1]].kind in BATCHED]
        share = len({k[2] for k in wanted if rows[k[1]].kind in BATCHED})  # (a resumed run: the same shapes)
        object_set = object_set_from_config(dataset.objects)  # (before the frames' thread: it uses the same one)
        first = None  # the batched rows' first frames, made (the renderer built) while the classifiers load
        frames_ahead = scene_set.on_device if FRAMES_AHEAD is None else FRAMES_AHEAD
        if frames_ahead and batched_todo and scene_set.loads_beside_renders():
            devices = batched.mesh().devices.size  # (run_batched's mesh)
            slots = chunk_plan(config, sorted({k[2] for k in batched_todo}), share, devices)[2][0]
            first = FirstFrames(render_order(slots), scene_set.chunk_ahead(render_order(slots)))
            first.frames.add_done_callback(lambda _: clock.mark(FIRST_FRAMES_MADE))
        classifiers: dict[str, pointnet.Classifier] = {}
        loading: dict[str, list[Future]] = {}

        def load_classifiers(names: Sequence[str] = tuple(config.classifiers)) -> None:
            """Those of the classifiers ``names`` not loaded yet, each one's batched programs loaded from the cache
            as soon as it is (on threads, beside the next classifier's load, the first frames and the calls)."""
            for name in names:
                if name not in classifiers:
                    classifiers[name] = setup.load_classifier(config.classifiers[name], object_set,
                                                              f"classifiers.{name}")
                    loading[name] = load_batched_ahead(config, scene_set, dataset, {name: classifiers[name]},
                                                       object_set, batched_todo, share)

        later = LATER_CLASSIFIERS and bool(batched_todo) and scene_set.loads_beside_renders()
        # (where ``later``: the first call's classifier now, the others once that call is out: ``run_batched``'s
        # ``more``)
        load_classifiers([next(c for c in config.classifiers if any(k[0] == c for k in batched_todo))] if later
                         else tuple(config.classifiers))
        clock.mark(CLASSIFIERS_LOADED)
        mark_when_done([f for futures in loading.values() for f in futures], clock, PROGRAMS_LOADED)
    mine = process_store(store, (index, count))  # where this process appends
    with tqdm(total=len(wanted), initial=len(wanted) - len(todo), desc="episodes", unit="episode",
              disable=not show_progress) as bar:
        oracle_todo = [k for k in todo if rows[k[1]].kind is protocol.Kind.ORACLE]
        oracle_loading: list[Future] = []  # the oracle's programs being loaded (run_oracle waits for them)

        def load_oracle() -> None:
            oracle_loading.extend(load_oracle_ahead(config, scene_set, dataset, classifiers, object_set, oracle_todo,
                                                    oracle))

        if batched_todo:
            # (the oracle's program loaded while the batched rows' last calls run, after their last render)
            stored += run_batched(config, scene_set, dataset, classifiers, object_set, batched_todo, mine, bar, clock,
                                  share, then=load_oracle, first=first, loading=loading,
                                  more=load_classifiers if later else None)
        else:
            load_oracle()
        load_classifiers()  # (every one loaded already, unless no batched call needed one)
        if oracle_todo:
            stored += run_oracle(config, scene_set, dataset, classifiers, object_set, oracle[index::count], done,
                                 mine, bar, clock, oracle_frames(config, oracle), oracle_loading)
        todo = [k for k in todo if rows[k[1]].kind not in (*BATCHED, protocol.Kind.ORACLE)]
        programs = [(c, name) for c in classifiers for name in rows if any(k[:2] == (c, name) for k in todo)]
        for group in passes(programs, jax.default_backend()):
            episodes: dict[tuple[str, str], active.Episode] = {}
            for s in range(scene_set.count):
                scene_todo = [k for k in todo if k[2] == s and k[:2] in group]
                if not scene_todo:
                    continue
                with clock("frames (rendered or read)"):
                    views = scene_set.load([s])[0]
                truth = scoring.Truth.from_scene(views.scene, object_set)
                starts = protocol.start_views(config.seed, s, config.runs, len(views.T_wc))
                keys = protocol.run_keys(config.seed, s, config.runs)
                for c, name in group:
                    missing = sorted(k[3] for k in scene_todo if k[:2] == (c, name))
                    if not missing:
                        continue
                    row = rows[name]
                    if (c, name) not in episodes:
                        episodes[c, name] = episode(config, row, classifiers[c], object_set, views.intrinsics,
                                                    views.table_height, dataset.scene.split, name=c)
                    bar.set_postfix(scene=s, classifier=c, row=name)
                    with clock("scene by scene (PointNetFull)"):
                        records = row_records(config, row, episodes[c, name], views, truth, starts, keys, missing)
                    records = [{"classifier": c, "row": name, "scene": s, **r} for r in records]
                    io.append_jsonl(mine, records)
                    stored += records
                    bar.update(len(records))
            jax.clear_caches()  # the pass's compiled programs (and their memory maps) go
    clock.episodes += len(batched_todo) + len(oracle_todo) + len(todo)
    if owner and clock.episodes:
        write_run_times(run_times_file(store, (index, count)), clock, time.perf_counter() - began)
    keep = set(every)
    return [r for r in stored if record_key(r) in keep]  # (what was read at the start, and what this run added)


def episode_keys(config: Table1Config, scenes: int) -> list[tuple[str, str, int, int]]:
    """Every (classifier, row, scene, run) episode of ``config`` over ``scenes`` scenes (the oracle's on its first
    ``oracle_scenes``), scene by scene."""
    rows = {name: protocol.row(name) for name in config.rows}
    return [(c, name, s, run) for s in range(scenes) for c in config.classifiers for name, row in rows.items()
            if row.kind is not protocol.Kind.ORACLE or s < config.oracle_scenes
            for run in range(runs_of(row, config.runs))]


def program_row(row: protocol.Row) -> protocol.Row:
    """The policy row whose episodes give ``row``'s: itself, or for PointNetSingle (GR on or off) the paper's
    VisOcclHist with the same GR, whose first move is PointNetSingle's move (the policy only picks the next
    view)."""
    if row.kind is protocol.Kind.SINGLE:
        return dataclasses.replace(row, kind=protocol.Kind.POLICY, policy=nbv.PolicyName.vis_occl_hist)
    return row


def run_batched(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig,
                classifiers: dict[str, pointnet.Classifier], object_set, todo: list[tuple[str, str, int, int]],
                store: Path, bar: tqdm, clock: Phases | None = None, planned: int | None = None,
                then: Callable[[], None] | None = None, first: FirstFrames | None = None,
                loading: dict[str, list[Future]] | None = None,
                more: Callable[[], None] | None = None) -> list[dict[str, Any]]:
    """The single-view and policy rows' episodes ``todo`` batched over scenes and runs and sharded over the
    local devices (``episode.batched``): the frames of ``scene_chunk`` of ``todo``'s scenes at a time (rounded up
    to a multiple of the devices), split by scene over the devices (each holds 1/n of them and runs their
    episodes), one switched program per classifier and model library running every row (``Episode.switched``),
    at most ``batch_episodes`` episodes a call (whole scenes, as many on every device: at least one scene's runs
    a device, n x runs episodes, whatever ``batch_episodes`` says). Rows that share a program row
    (PointNetSingle and VisOcclHist with the same GR) share its episodes. A call's records are built and appended
    while the next call runs on the devices. Returns the records appended. The chunks' and calls' sizes follow
    from ``planned`` scenes (the whole run's share, so that a resumed run has the first one's shapes and
    compiles nothing; default: ``todo``'s). With the compilation cache on, each program is read and compiled
    (loaded) on a background thread (``compile_cache.ahead``) while the host builds the renderer and renders the
    first chunk, and a classifier's waited for before its first call (the first call waits for its own program
    alone, the others load meanwhile); where the renderer forbids a load beside a render
    (``Scenes.loads_beside_renders``: MuJoCo Warp's own graph capture), all of them before the first render. ``then`` is
    called once the last chunk's frames are rendered and in use, with no render to come here (e.g. to load the
    next rows' programs while the last calls run). ``first``: the first chunk's frames being made already (on a
    thread, ``Scenes.chunk_ahead``: its renderer built there too), used where they are of its scenes.
    ``loading``: the programs' loads started already, by classifier (``load_batched_ahead`` with the same ``todo``
    and ``planned``: ``run_episodes`` starts each classifier's as soon as it is loaded); default: started here.
    ``more``: adds the classifiers of ``todo`` that ``classifiers`` lacks to it, and their loads to ``loading``
    (``run_episodes``: those it left out of the first call's start), called once the first call is dispatched, or
    before, where a call needs one of them."""
    clock = clock or Phases()
    device_mesh = batched.mesh()
    policies = tuple(dict.fromkeys(program_row(protocol.ROWS[k[1]]).policy for k in todo))
    switched: dict[tuple[str, str], active.Episode] = {}
    pending: list = []  # the call in flight: (its episodes' keys by row, traces, truths, starts, scene positions,
    # whether it is of the last chunk)
    then_called: list = []
    dispatched: list = []  # (once the first call is)
    made: list[dict[str, Any]] = []  # the records appended

    def episodes_clock():
        """Dispatching a call (the first one compiles, or waits for its program loaded ahead) and waiting for
        one: the devices' share of the run."""
        return clock("batched episodes" if dispatched else FIRST_CALL)

    def finish() -> None:
        calls, traces, truths, start, at, last = pending.pop()
        with episodes_clock():
            traces = batched.fetch(traces, len(start))
        if last and then is not None and not then_called:  # (its chunk's frames rendered: no render to come)
            then()
            then_called.append(True)
        with clock("records (labels matched to the objects)"):
            for (c, name), keys in calls.items():
                moves = 1 if protocol.ROWS[name].kind is protocol.Kind.SINGLE else config.moves
                index = np.array([e for e, _ in keys], np.int64)
                records = protocol.episode_records(
                    jax.tree.map(lambda x, i=index, m=moves: x[i, :m], traces), [truths[at[k[2]]] for _, k in keys],
                    [{"classifier": c, "row": name, "scene": k[2], "run": k[3], "start": int(start[i])}
                     for i, k in keys])
                io.append_jsonl(store, records)
                made.extend(records)
                bar.update(len(records))

    scenes = sorted({k[2] for k in todo})  # (a process of several: its share)
    n = device_mesh.devices.size
    _, per_call, layouts = chunk_plan(config, scenes, planned, n)
    size = per_call * n * config.runs
    if loading is None:  # (the programs loaded while the host builds the renderer)
        loading = {c: load_batched_ahead(config, scene_set, dataset, {c: classifiers[c]}, object_set, todo, planned)
                   for c in classifiers}
    # (each waited for before its first call; ``more`` adds to the caller's dict, so it is read, not copied)
    todo_classifiers = [c for c in config.classifiers if any(k[0] == c for k in todo)]
    if first is None:
        with clock("frames (rendered or read)"):
            scene_set.prepare_renderer()

    def loaded(c: str | None = None) -> None:
        """Classifier ``c``'s programs loaded (None: every one), as far as the renderer's set-up, the frames and
        the earlier calls did not hide their loads."""
        for name in loading if c is None else [c]:
            wait_for(loading.get(name, []), episodes_clock)

    if not scene_set.loads_beside_renders():
        loaded()
    for number, slots in enumerate(layouts):  # the scene in each frame slot (device d: slots d per ...)
        chunk_scenes = sorted(set(slots))
        at = {}  # a scene's slot in the chunk's frames (its first, where padding repeats it)
        for slot, s in enumerate(slots):
            at.setdefault(s, slot)
        chunk_todo = [k for k in todo if k[2] in at]
        groups = call_scenes(slots, n, per_call)
        with clock("frames (rendered or read)"):
            order = render_order(slots)
            early = first.frames.result() if number == 0 and first is not None else None  # (one render at a time)
            if early is not None and first.scenes != order:
                warnings.warn(f"Table 1: the first frames made ahead are of scenes {first.scenes[:4]}..., not the "
                              f"first chunk's {order[:4]}...: rendered again", stacklevel=2)
                early = None
            chunk = early if early is not None else scene_set.chunk(order)
            place = {s: i for i, s in enumerate(order)}
            laid = np.array([place[s] for s in slots])
            depth, T_wc = (x if np.array_equal(laid, np.arange(len(x))) else x[laid] for x in (chunk.depth, chunk.T_wc))
            depth, T_wc = batched.split_frames(depth, device_mesh), batched.split_frames(T_wc, device_mesh)
        truths = [scoring.Truth.from_scene(chunk.scenes[i], object_set) for i in laid]  # by slot
        V = chunk.T_wc.shape[1]
        starts = {s: protocol.start_views(config.seed, s, config.runs, V) for s in chunk_scenes}
        with jax.default_device(devices.host_cpu()):  # (on a GPU they would wait for its queue)
            keys = {s: np.asarray(protocol.run_keys(config.seed, s, config.runs)) for s in chunk_scenes}
        for c in todo_classifiers:
            programs: dict[tuple, tuple[protocol.Row, list[str]]] = {}  # (policy, GR, library) -> the rows it gives
            for name in dict.fromkeys(k[1] for k in chunk_todo if k[0] == c):
                row = program_row(protocol.ROWS[name])
                programs.setdefault((row.policy, row.refinement, row.library), (row, []))[1].append(name)
            if programs and c not in classifiers and more is not None:  # (needed before the first call went out)
                more()
                more = None
            for row, names in programs.values():
                if (c, row.library) not in switched:
                    switched[c, row.library] = episode(config, row, classifiers[c], object_set, chunk.intrinsics,
                                                       chunk.scenes[0].table_height, dataset.scene.split, name=c)
                    switched[c, row.library] = switched[c, row.library].switched(policies)
                chosen = switched[c, row.library].choose(row.policy, row.refinement)
                for in_call in groups:
                    call = sorted({k[2:] for k in chunk_todo if k[0] == c and k[1] in names and k[2] in in_call})
                    if not call:
                        continue
                    index = {sr: e for e, sr in enumerate(call)}  # (scene, run) -> its place in the call
                    scene = np.array([at[s] for s, _ in call], np.int32)
                    start = np.array([starts[s][r] for s, r in call], np.int32)
                    key = np.stack([keys[s][r] for s, r in call])
                    bar.set_postfix(scenes=f"{chunk_scenes[0]}-{chunk_scenes[-1]}", classifier=c,
                                    rows="+".join(names))
                    loaded(c)
                    with episodes_clock():
                        traces = batched.dispatch(chosen, depth, T_wc, scene, start, key, device_mesh, size,
                                                  split_scenes=True, kernels=config.kernels)
                    clock.mark(FIRST_CALL_DISPATCHED)
                    dispatched.append(True)
                    if more is not None:  # (the classifiers left out of the start, loaded while this call runs)
                        more()
                        more = None
                    if pending:
                        finish()  # the last call's records, while this one runs
                    calls = {(c, name): [(index[k[2:]], k) for k in chunk_todo
                                         if k[:2] == (c, name) and k[2:] in index] for name in names}
                    pending.append((calls, traces, truths, start, at, number == len(layouts) - 1))
    if pending:
        finish()  # (every chunk has a call: the last chunk's first finished one has called ``then``)
    return made


def load_batched_ahead(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig,
                       classifiers: dict[str, pointnet.Classifier], object_set, todo: list[tuple[str, str, int, int]],
                       planned: int | None = None) -> list[Future]:
    """With the compilation cache on, the batched program (``Episode.switched``) of each (classifier of
    ``classifiers``, model library) of ``todo`` read and compiled (loaded) on a background thread
    (``compile_cache.ahead``) for ``run_batched``'s frames and calls (``chunk_plan`` of ``todo``'s scenes and
    ``planned``, on every local device), while the host does other work: loads the next classifier, builds the
    renderer, renders the first chunk. Returns the loads' Futures (``run_batched`` waits for them before its
    first call, or its first render where the renderer forbids a load beside it); none without the cache. The
    programs' shapes and policies follow from the whole ``todo``, as ``run_batched``'s do, whichever classifiers
    ``classifiers`` holds (those of ``todo`` it lacks are loaded by another call: ``run_episodes`` loads each
    classifier's as soon as that classifier is)."""
    if not (any(k[0] in classifiers for k in todo) and compile_cache.enabled()):
        return []
    device_mesh = batched.mesh()
    n = device_mesh.devices.size
    per, per_call, _ = chunk_plan(config, sorted({k[2] for k in todo}), planned, n)
    policies = tuple(dict.fromkeys(program_row(protocol.ROWS[k[1]]).policy for k in todo))
    intrinsics, table_height, views = scene_set.frame_layout()
    frames = (n * per, views, intrinsics.height, intrinsics.width)

    def load(c: str, row: protocol.Row) -> None:
        built = episode(config, row, classifiers[c], object_set, intrinsics, table_height, dataset.scene.split,
                        name=c)
        batched.prepare(built.switched(policies), frames, per_call * n * config.runs, device_mesh, split_scenes=True,
                        kernels=config.kernels)

    libraries: dict[tuple[str, Any], protocol.Row] = {}  # (classifier, library) -> a row of its program
    for k in todo:
        row = program_row(protocol.ROWS[k[1]])
        if k[0] in classifiers:
            libraries.setdefault((k[0], row.library), row)
    return [compile_cache.ahead(functools.partial(load, c, row), f"Table 1's batched program ({c}, {library})")
            for (c, library), row in libraries.items()]


def mark_when_done(futures: Sequence[Future], clock: Phases, name: str) -> None:
    """``clock.mark(name)`` once every one of ``futures`` is done (at once where there are none: nothing)."""
    left = [len(futures)]
    lock = threading.Lock()

    def done(_: Future) -> None:
        with lock:
            left[0] -= 1
            last = left[0] == 0
        if last:
            clock.mark(name)

    for future in futures:
        future.add_done_callback(done)


def load_oracle_ahead(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig,
                      classifiers: dict[str, pointnet.Classifier], object_set, todo: list[tuple[str, str, int, int]],
                      calls: list[list[tuple[str, str, int, int]]]) -> list[Future]:
    """With the compilation cache on, the oracle's program for each (classifier, row) of ``todo`` read and
    compiled (loaded) on a background thread (``compile_cache.ahead``), for ``run_oracle``'s frames (every
    process's ``calls``: ``oracle_frames``) and calls, while the host does other work (``run_oracle`` waits for
    the loads returned before its first call, or its first render where the renderer forbids a load beside it)."""
    if not (todo and compile_cache.enabled()):
        return []
    intrinsics, table_height, views = scene_set.frame_layout()
    frames = (oracle_frames(config, calls), views, intrinsics.height, intrinsics.width)

    def load(c: str, name: str) -> None:
        built = episode(config, protocol.ROWS[name], classifiers[c], object_set, intrinsics, table_height,
                        dataset.scene.split, name=c)
        protocol.prepare_oracle(built, frames, oracle_call_size(config), config.kernels)

    return [compile_cache.ahead(functools.partial(load, c, name), f"the oracle's program ({c}, {name})")
            for c, name in dict.fromkeys(k[:2] for k in todo)]


def oracle_calls(config: Table1Config, keys: list[tuple[str, str, int, int]]) -> list[list[tuple[str, str, int, int]]]:
    """The oracle's calls: each (classifier, row)'s episodes ``keys`` in (scene, run) order, ``oracle_runs_per_call``
    a call (0: one on a CPU, ``ORACLE_EPISODES_PER_CALL`` elsewhere). The calls are the same for every process
    count, and process i of N runs calls i, i + N, ...: a call's episodes and its shape do not depend on N, and
    the processes' shares differ by at most a call."""
    size = oracle_call_size(config)
    calls = []
    for program in dict.fromkeys(k[:2] for k in keys):
        ordered = sorted((k for k in keys if k[:2] == program), key=operator.itemgetter(2, 3))
        calls += [ordered[i:i + size] for i in range(0, len(ordered), size)]
    return calls


def oracle_call_size(config: Table1Config) -> int:
    """Episodes in each of the oracle's calls: ``oracle_runs_per_call``, or (0) one on a CPU and
    ``ORACLE_EPISODES_PER_CALL`` elsewhere."""
    return config.oracle_runs_per_call or (1 if jax.default_backend() == "cpu" else ORACLE_EPISODES_PER_CALL)


def oracle_frames(config: Table1Config, calls: list[list[tuple[str, str, int, int]]]) -> int:
    """Scenes' frames in each of the oracle's calls (every process's ``calls``): min(``scene_chunk``, the oracle's
    scenes), at least a call's scenes. One shape whatever a process's share and however far a run got."""
    scenes = {k[2] for call in calls for k in call}
    return max(min(config.scene_chunk, len(scenes)), *(len({k[2] for k in call}) for call in calls), 1)


def run_oracle(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig,
               classifiers: dict[str, pointnet.Classifier], object_set,
               calls: list[list[tuple[str, str, int, int]]], done: set, store: Path, bar: tqdm, clock: Phases,
               frames: int, loading: Sequence[Future] = ()) -> list[dict[str, Any]]:
    """The oracle row's ``calls`` (``oracle_calls``; this process's) with an episode not in ``done``, each one call
    of ``protocol.oracle_rollouts`` over the runs of its scenes, padded to the calls' size (copies of its first
    episode, dropped); the frames of consecutive calls' scenes at a time, ``frames`` scenes (``oracle_frames``;
    padded with copies of the first scene's, never used). A call runs whole, as every process count and an
    uninterrupted run have it; its episodes not in ``done`` are appended to ``store`` and returned. ``loading``:
    programs being loaded ahead (``load_oracle_ahead``), waited for before the first call (before the first render
    where the renderer forbids a load beside it: ``Scenes.loads_beside_renders``)."""
    loading = list(loading)

    def loaded() -> None:
        wait_for(loading, lambda: clock("the oracle (runs of several scenes a call)"))

    if not scene_set.loads_beside_renders():
        loaded()
    calls = [call for call in calls if any(k not in done for k in call)]
    size = oracle_call_size(config)  # (every call padded to it: a resumed run's last, shorter call too)
    episodes: dict[tuple[str, str], active.Episode] = {}
    made: list[dict[str, Any]] = []
    at = 0
    while at < len(calls):
        group, scenes = [], set()  # consecutive calls whose scenes' frames fit in ``frames``
        while at < len(calls) and len(scenes | {k[2] for k in calls[at]}) <= frames:
            scenes |= {k[2] for k in calls[at]}
            group.append(calls[at])
            at += 1
        chunk_scenes = sorted(scenes)
        with clock("frames (rendered or read)"):
            chunk = scene_set.chunk(chunk_scenes)
            depth, T_wc = jnp.asarray(chunk.depth, jnp.float32), chunk.T_wc  # (on the device once for the chunk)
            if len(chunk_scenes) < frames:
                slots = np.r_[np.arange(len(chunk_scenes)), np.zeros(frames - len(chunk_scenes), np.int64)]
                depth, T_wc = depth[slots], T_wc[slots]
        place = {s: i for i, s in enumerate(chunk_scenes)}
        truths = {s: scoring.Truth.from_scene(chunk.scenes[i], object_set) for s, i in place.items()}
        starts = {s: protocol.start_views(config.seed, s, config.runs, chunk.T_wc.shape[1]) for s in chunk_scenes}
        with jax.default_device(devices.host_cpu()):  # (on a GPU they would wait for its queue)
            keys = {s: np.asarray(protocol.run_keys(config.seed, s, config.runs)) for s in chunk_scenes}
        for call in group:
            c, name = call[0][:2]
            if (c, name) not in episodes:
                episodes[c, name] = episode(config, protocol.ROWS[name], classifiers[c], object_set, chunk.intrinsics,
                                            chunk.scenes[0].table_height, dataset.scene.split, name=c)
            padded = call + [call[0]] * (size - len(call))
            bar.set_postfix(scenes=f"{call[0][2]}-{call[-1][2]}", classifier=c, row=name)
            loaded()
            with clock("the oracle (runs of several scenes a call)"):
                traces = protocol.oracle_rollouts(
                    episodes[c, name], depth, T_wc, np.array([starts[s][r] for _, _, s, r in padded]),
                    np.stack([keys[s][r] for _, _, s, r in padded]), [truths[s] for _, _, s, _ in padded],
                    scene=np.array([place[s] for _, _, s, _ in padded]), kernels=config.kernels,
                    label=protocol.ROWS[name].scored_by, policy_last=protocol.ROWS[name].policy_last)
            new = np.array([i for i, k in enumerate(call) if k not in done])
            records = protocol.episode_records(
                jax.tree.map(lambda x, i=new: x[i], traces), [truths[call[i][2]] for i in new],
                [{"classifier": c, "row": name, "scene": call[i][2], "run": call[i][3],
                  "start": int(starts[call[i][2]][call[i][3]])} for i in new])
            io.append_jsonl(store, records)
            made.extend(records)
            bar.update(len(records))
    return made  # (its one program a classifier is kept: a second run in this process, e.g. a share, reuses it)


def chosen_episodes(config: Table1Config, chosen: list[str]) -> list[tuple[str, str, int, int]]:
    """``--record``'s episodes as (classifier, row, scene, run): each ``ROW:SCENE:RUN`` or
    ``CLASSIFIER:ROW:SCENE:RUN`` (the config's first classifier when left out); ValueError naming the entry for
    another syntax, a classifier or row the config does not run, a row that is not a single-view or policy
    row, or a run out of range (the scene's range is checked where the scenes are known)."""
    wanted = []
    for text in chosen:
        parts = text.split(":")
        if len(parts) == 3:
            parts = [next(iter(config.classifiers)), *parts]
        if len(parts) != 4 or not parts[2].isdigit() or not parts[3].isdigit():
            raise ValueError(f"--record {text!r}: expected ROW:SCENE:RUN or CLASSIFIER:ROW:SCENE:RUN")
        c, name, s, r = parts[0], parts[1], int(parts[2]), int(parts[3])
        if c not in config.classifiers or name not in config.rows:
            raise ValueError(f"--record {text!r}: classifier {c!r} / row {name!r} not among the config's "
                             f"{sorted(config.classifiers)} / {list(config.rows)}")
        if protocol.row(name).kind not in BATCHED:
            raise ValueError(f"--record {text!r}: only the single-view and policy rows are recorded")
        if r >= config.runs:
            raise ValueError(f"--record {text!r}: run must lie in 0..{config.runs - 1}")
        wanted.append((c, name, s, r))
    return wanted


def record_episodes(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig, chosen: list[str],
                    folder: Path) -> list[Path]:
    """The ``chosen_episodes`` again, move by move on the host (``runner.run``: the table's start view and key),
    each recorded for rerun's 3-D viewer (``episode.viewer``) as ``folder/<classifier>_<row>_scene<S>_run<R>
    .rrd`` (PointNetSingle: its one move). The replayed episode is the host path's: the batched program rounds
    otherwise in the last bits, as any other compilation does."""
    from jaxcls.episode.viewer import EpisodeRecording

    wanted = chosen_episodes(config, chosen)
    for c, name, s, _ in wanted:
        if s >= scene_set.count:
            raise ValueError(f"--record {c}:{name}:{s}: scene must lie in 0..{scene_set.count - 1}")
    object_set = object_set_from_config(dataset.objects)
    classifiers = {c: setup.load_classifier(config.classifiers[c], object_set, f"classifiers.{c}")
                   for c in dict.fromkeys(w[0] for w in wanted)}
    written = []
    for c, name, s, r in wanted:
        classifier = classifiers[c]
        views = scene_set.load([s])[0]
        row = protocol.row(name)
        ep = episode(config, program_row(row), classifier, object_set, views.intrinsics, views.table_height,
                     dataset.scene.split, name=c)
        if row.kind is protocol.Kind.SINGLE:
            ep = dataclasses.replace(ep, config=dataclasses.replace(ep.config, moves=1))
        start = protocol.start_views(config.seed, s, config.runs, len(views.T_wc))[r]
        recorder = EpisodeRecording(ep, views.T_wc, classifier.classes, views.scene, object_set,
                                    name=f"{c} {name} scene {s} run {r}")
        runner.run(ep, views, int(start), protocol.run_keys(config.seed, s, config.runs)[r],
                   scoring.Truth.from_scene(views.scene, object_set), on_move=recorder.move)
        written.append(recorder.write(folder / f"{c}_{name}_scene{s:04d}_run{r}.rrd"))
    return written


def wait_for(loading: list[Future], timer: Callable[[], contextlib.AbstractContextManager]) -> None:
    """Wait for the programs being loaded ahead (``compile_cache.ahead``) under ``timer()``'s phase, emptying
    ``loading`` (a second call waits for nothing): before a row's first call, or before its first render where
    the renderer forbids a load beside it (``Scenes.loads_beside_renders``)."""
    if loading:
        with timer():
            while loading:
                loading.pop(0).result()


@dataclasses.dataclass(frozen=True)
class FirstFrames:
    """The batched rows' first chunk's frames being made ahead: its ``scenes`` in render order (``render_order``)
    and the ``Chunk``'s Future (``Scenes.chunk_ahead``)."""

    scenes: list[int]
    frames: Future[Chunk]


def chunk_plan(config: Table1Config, scenes: list[int], planned: int | None,
               devices: int) -> tuple[int, int, list[list[int]]]:
    """(scenes a device holds in a chunk, scenes a device runs in a call, each chunk's frame slots) of the
    batched rows' ``scenes`` (sorted) over ``devices``. The frames split by scene over the devices, ``per``
    scenes each (a chunk round-robin, ``chunk_layout``, so that a call of consecutive scenes keeps every device
    busy); a call takes ``per_call`` scenes of each device. One shape for every call: a last, shorter chunk and
    call padded (copies, dropped), so that nothing compiles again (~20 s a shape on an H200); the sizes from
    ``planned`` scenes (the whole run's share; default ``scenes``') balanced so that little is padded."""
    per, per_call = chunk_sizes(max(planned or 0, len(scenes)), devices, config.scene_chunk, config.batch_episodes,
                                config.runs)
    step = devices * per
    return per, per_call, [chunk_layout(scenes[first:first + step], devices, per)
                           for first in range(0, len(scenes), step)]


def render_order(slots: list[int]) -> list[int]:
    """A chunk's scenes in slot order, each once: what ``Scenes.chunk`` renders for ``slots`` (``chunk_layout``;
    a full chunk needs no reordering)."""
    return list(dict.fromkeys(slots))


def chunk_sizes(scenes: int, devices: int, scene_chunk: int, batch_episodes: int, runs: int) -> tuple[int, int]:
    """(scenes a device holds in a chunk, scenes a device runs in a call) for ``scenes`` scenes over ``devices``:
    chunks of at most ``scene_chunk`` scenes rounded up to the devices, calls of at most ``batch_episodes``
    episodes (0: a chunk a call; at least one scene a device), both evened out over the chunks and calls they
    need, so that the last is padded by less than one scene a device (250 scenes in chunks of at most 100 on
    one device: 3 chunks of 84, not 100, 100 and 50 padded to 100)."""
    per = -(-min(scene_chunk, scenes) // devices)  # (the largest chunk's share of a device)
    chunks = -(-scenes // (devices * per))
    per = -(-scenes // (chunks * devices))
    per_call = max(1, min(per, batch_episodes // (devices * runs))) if batch_episodes else per
    calls = -(-per // per_call)
    return per, -(-per // calls)


def chunk_layout(chunk_scenes: list[int], devices: int, per: int) -> list[int]:
    """The scene in each of ``devices * per`` frame slots (device d holds slots [d per, (d+1) per)): the chunk's
    scenes dealt round-robin (device d: scenes d, d + devices, ...), each device's last slots repeating its
    first scene (the chunk's first, where it has none)."""
    blocks = [chunk_scenes[d::devices] for d in range(devices)]
    if any(len(block) > per for block in blocks):
        raise ValueError(f"chunk_layout: {len(chunk_scenes)} scenes do not fit {devices} x {per} slots")
    return [s for block in blocks for s in block + [(block or chunk_scenes)[0]] * (per - len(block))]


def call_scenes(slots: list[int], devices: int, per_call: int) -> list[set[int]]:
    """The scenes of each call over a chunk laid out in ``slots`` (``chunk_layout``): ``per_call`` slots of
    every device a call, each scene once (a padding slot's scene runs from its first slot)."""
    per = len(slots) // devices
    first = {}
    for slot, s in enumerate(slots):
        first.setdefault(s, slot)
    return [{slots[d * per + j] for d in range(devices) for j in range(part, min(part + per_call, per))
             if first[slots[d * per + j]] == d * per + j} for part in range(0, per, per_call)]


def episode(config: Table1Config, row: protocol.Row, classifier: pointnet.Classifier, object_set,
            intrinsics: Intrinsics, table_height: float, scene_split: str, *, name: str) -> active.Episode:
    """``row``'s episode of this config's move settings for the classifier ``name`` (its learned policy:
    ``Table1Config.nbv_of``; ``Row.episode`` owns the wiring)."""
    base = setup.ActiveConfig(episode=active.EpisodeConfig(decision=config.decision), perception=config.perception,
                              refine=config.refine, nbv=config.nbv_of(name))
    return row.episode(base, config.moves, classifier, object_set, intrinsics, table_height, scene_split)


def row_records(config: Table1Config, row: protocol.Row, episode: active.Episode, views: sources.Preloaded,
                truth: scoring.Truth, starts: np.ndarray, keys: jax.Array, runs: list[int]) -> list[dict]:
    """The records of ``runs`` of one row on one scene."""
    if row.kind is protocol.Kind.FULL:
        trace, _ = protocol.all_views(episode, views.depth, views.T_wc, keys[0])
        return [protocol.episode_record(trace, truth, run=0, start=-1)]
    # All runs (one compiled shape), brought to the host once.
    traces = jax.device_get(protocol.rollouts(episode, views.depth, views.T_wc, starts, keys))
    runs_index = np.asarray(runs, np.int64)
    return protocol.episode_records(jax.tree.map(lambda x: np.asarray(x)[runs_index], traces), [truth] * len(runs),
                                    [{"run": r, "start": int(starts[r])} for r in runs])


def time_modules(config: Table1Config, scene_set: Scenes, dataset: DatasetConfig) -> dict[str, Any]:
    """One VisOcclHistGR episode of the first scene, each module timed outside jit (``runner.run``): the
    median ms per module over its moves after the first, per classifier's weights (the first's)."""
    object_set = object_set_from_config(dataset.objects)
    name, path = next(iter(config.classifiers.items()))
    classifier = setup.load_classifier(path, object_set, f"classifiers.{name}")
    views = scene_set.load([0])[0]
    row = protocol.ROWS["vis_occl_hist_gr"]
    timed = episode(dataclasses.replace(config, moves=config.timing_moves), row, classifier, object_set,
                    views.intrinsics, views.table_height, dataset.scene.split, name=name)
    start = int(protocol.start_views(config.seed, 0, 1, len(views.T_wc))[0])
    runner.run(timed, views, start, jax.random.PRNGKey(config.seed))  # compiles
    log = runner.run(timed, views, start, jax.random.PRNGKey(config.seed))
    times = {m: float(np.median([mv["times_ms"][m] for mv in log.moves[1:] or log.moves])) for m in active.MODULES}
    return {"device": report.device_name(), "cpu": report.cpu_name(), "moves": len(log.moves), "times_ms": times}
