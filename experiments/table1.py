"""The paper's Table 1 and Figure 4: every row's episodes on a dataset's scenes, with confidence intervals.

    python experiments/table1.py --config table1_synthetic [key=value ...] [--out RESULTS.md]
    python experiments/table1.py --config table1_real_like

The scenes are a ``jaxcls dataset`` (``dataset``: a shipped dataset config name, a config path, or a folder
written by ``jaxcls dataset``; a config's folder is rendered first if it is missing or incomplete, and
``dataset_overrides`` change it, e.g. ``[num_scenes=30,out_dir=data/synthetic_30]``). The rows are
``protocol.ROWS`` names (``rows``); each runs ``runs`` episodes per scene from seeded random start views
(the same starts and keys for every row: rows are paired), ``moves`` moves each, with every classifier of
``classifiers`` (name: a ``.msgpack`` path or a shipped name, "" = the shipped weights). The oracle row
runs on the first ``oracle_scenes`` scenes only (it tries every candidate at every move), a scene's runs
together on an accelerator (``oracle_runs_per_call``). On a GPU, float32 products run at full precision
(``jaxcls.precision``).

Episodes stream to ``out_dir/episodes.jsonl`` as each scene's runs of a row finish; running the command
again skips what is there (an interrupted run resumes without redoing or losing an episode; a torn last
line is dropped). Same config, same numbers. Outputs in ``out_dir``: ``table.md`` (the table laid out as the
paper's, per classifier, then the paired differences and moves-to-correct), ``table.csv`` (every row x
move), ``figure4.png`` (F1 over moves, with 95% bands), ``timing.json`` (each module's time per move).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io as _io
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import compile_cache, io, metrics, precision, report, viz
from jaxcls.config import ConfigError, bounded, check_bounds, load_config, resolve_config, save_config
from jaxcls.episode import active, protocol, runner, scoring, setup, sources
from jaxcls.perception import pointnet
from jaxcls.perception.refine import RefineConfig
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.planning.nbv import NBVConfig
from jaxcls.world.dataset import DatasetConfig, build_dataset, scene_file
from jaxcls.world.objects import object_set_from_config

PAPER_TIMES_MS = {"reconstruction": 120, "segmentation": 60, "refinement": 880, "planning": 190}
STATISTICS = ("accuracy", "precision", "recall", "f1")


@dataclasses.dataclass(frozen=True)
class Table1Config:
    """``experiments/table1.py``: which scenes, rows, runs and classifiers; the move's settings."""

    out_dir: str = "runs/table1_synthetic"
    dataset: str = "synthetic"  # a dataset config (name or path) or a folder written by ``jaxcls dataset``
    dataset_overrides: tuple[str, ...] = ()  # key=value changes to a dataset config (num_scenes, out_dir, ...)
    seed: int = 0  # start views and episode keys
    scenes: int = bounded(0, ge=0)  # the first this many scenes of the dataset; 0 = all
    runs: int = bounded(10, ge=1)  # episodes per scene and row, from random start views
    moves: int = bounded(10, ge=1)  # T
    rows: tuple[str, ...] = protocol.PAPER_ROWS
    oracle_scenes: int = bounded(7, ge=0)  # the oracle row runs on the first this many scenes
    # The oracle's runs of a scene tried together (each tries every candidate at every move: runs x
    # candidates moves in one vmapped call, ~45 MB each at 640x480). 0: all of a scene's runs on an
    # accelerator (6.8x one at a time on an H100, BENCHMARKS.md), one at a time on the CPU (no faster there).
    oracle_runs_per_call: int = bounded(0, ge=0)
    # name: weights (a .msgpack path or a shipped name, "" = the shipped weights); no default, so that a
    # config's own list is the whole list (OmegaConf merges mappings into the defaults).
    classifiers: dict[str, str] = dataclasses.field(default_factory=dict)
    decision: active.Decision = "evidence"  # how a segment's class is decided (``active.EpisodeConfig``)
    perception: PerceptionConfig = dataclasses.field(default_factory=setup.episode_perception)
    refine: RefineConfig = dataclasses.field(default_factory=setup.episode_refine)
    nbv: NBVConfig = dataclasses.field(default_factory=setup.episode_nbv)
    timing_moves: int = bounded(10, ge=0)  # one VisOcclHistGR episode timed module by module (0 = none)
    resamples: int = bounded(2000, ge=100)  # bootstrap resamples

    def __post_init__(self) -> None:
        check_bounds(self)
        for name in self.rows:
            protocol.row(name, "rows")
        if not self.classifiers:
            raise ValueError("classifiers: name at least one (name: path, \"\" = the shipped weights)")

    def results_defining(self) -> dict[str, Any]:
        """What the stored episodes depend on (a rerun with another of these must use another out_dir)."""
        return {k: v for k, v in dataclasses.asdict(self).items()
                if k not in ("out_dir", "rows", "oracle_scenes", "oracle_runs_per_call", "timing_moves", "resamples",
                             "scenes")}


# --- the dataset -------------------------------------------------------------------------------------------

def dataset_config(config: Table1Config) -> DatasetConfig:
    """The dataset's config, from its folder or its name, without reading or rendering a scene."""
    folder = Path(config.dataset)
    if folder.is_dir() and (folder / "config.yaml").is_file():
        return load_config(DatasetConfig, folder / "config.yaml", config.dataset_overrides)
    return load_config(DatasetConfig, config.dataset, config.dataset_overrides)


def stored_records(config: Table1Config, store: Path) -> list[dict[str, Any]]:
    """The stored episodes of this config's classifiers, rows and first ``scenes`` scenes (all if 0)."""
    return [r for r in io.read_jsonl(store) if r["classifier"] in config.classifiers and r["row"] in config.rows
            and (not config.scenes or int(r["scene"]) < config.scenes)]


def open_dataset(config: Table1Config) -> tuple[DatasetConfig, list[Path]]:
    """The dataset's config and its scene files (``config.scenes`` of them), rendering a config's missing
    scenes first (``build_dataset`` resumes)."""
    folder = Path(config.dataset)
    if folder.is_dir():
        if not (folder / "config.yaml").is_file():
            raise ValueError(f"dataset: {folder} has no config.yaml; pass a folder written by `jaxcls dataset`")
        dataset = load_config(DatasetConfig, folder / "config.yaml", config.dataset_overrides)
        dataset = dataclasses.replace(dataset, out_dir=str(folder))
        files = sorted(folder.glob("scene_*.npz"))
        if not files:
            raise ValueError(f"dataset: {folder} holds no scene files (scene_NNN.npz)")
    else:
        try:
            resolve_config(config.dataset)
        except ConfigError as e:
            raise ValueError(f"dataset: {config.dataset!r} is neither a dataset folder nor a dataset config "
                             f"({e})") from None
        dataset = load_config(DatasetConfig, config.dataset, config.dataset_overrides)
        if config.scenes > dataset.num_scenes:
            raise ValueError(f"scenes: {config.scenes} scenes asked, the dataset {config.dataset!r} has "
                             f"{dataset.num_scenes} (dataset_overrides=[num_scenes={config.scenes},out_dir=...])")
        build_dataset(dataset)
        files = [scene_file(dataset.out_dir, i) for i in range(dataset.num_scenes)]
    if config.scenes > len(files):
        raise ValueError(f"scenes: {config.scenes} scenes asked, {folder} has {len(files)}")
    return dataset, files[:config.scenes or len(files)]


# --- the episodes, streamed to JSONL ------------------------------------------------------------------------

def _key(r: dict[str, Any]) -> tuple[str, str, int, int]:
    return r["classifier"], r["row"], int(r["scene"]), int(r["run"])


def _runs_of(row: protocol.Row, runs: int) -> int:
    return 1 if row.kind is protocol.Kind.FULL else runs


# Linux caps a process's memory maps (vm.max_map_count, 65530 by default). On XLA's CPU backend each compiled
# row program holds ~1,600-2,400 of them (its JIT-compiled code), so a process that kept every row's program
# died with LLVM's "Cannot allocate memory" after ~30. On the CPU the rows run in passes over the scenes of at
# most this many (classifier, row) programs each, freed after the pass (a scene is read once per pass).
CPU_PROGRAMS_PER_PASS = 12


def passes(programs: list, backend: str) -> list[list]:
    """``programs`` in the groups that run together: all at once off the CPU, ``CPU_PROGRAMS_PER_PASS`` on it."""
    size = CPU_PROGRAMS_PER_PASS if backend == "cpu" else max(1, len(programs))
    return [programs[i:i + size] for i in range(0, len(programs), size)]


def run_episodes(config: Table1Config, files: list[Path], dataset: DatasetConfig, store: Path,
                 show_progress: bool = True) -> list[dict[str, Any]]:
    """Every (classifier, row, scene, run) episode not yet in ``store`` (JSONL), appended as each scene's runs
    of a row finish; returns all records of this config's rows and scenes."""
    object_set = object_set_from_config(dataset.objects)
    classifiers = {name: setup.load_classifier(path, object_set, f"classifiers.{name}")
                   for name, path in config.classifiers.items()}
    rows = {name: protocol.row(name) for name in config.rows}
    done = {_key(r) for r in io.read_jsonl(store)}
    wanted = [(c, name, s, run) for s in range(len(files)) for c in classifiers for name, row in rows.items()
              if row.kind is not protocol.Kind.ORACLE or s < config.oracle_scenes
              for run in range(_runs_of(row, config.runs))]
    todo = [k for k in wanted if k not in done]
    programs = [(c, name) for c in classifiers for name in rows if any(k[:2] == (c, name) for k in todo)]
    with tqdm(total=len(wanted), initial=len(wanted) - len(todo), desc="episodes", unit="episode",
              disable=not show_progress) as bar:
        for group in passes(programs, jax.default_backend()):
            episodes: dict[tuple[str, str], active.Episode] = {}
            for s, path in enumerate(files):
                scene_todo = [k for k in todo if k[2] == s and k[:2] in group]
                if not scene_todo:
                    continue
                views = sources.dataset_source(path, dataset.objects)
                truth = scoring.Truth.from_scene(views.scene, object_set)
                starts = protocol.start_views(config.seed, s, config.runs, len(views.T_wc))
                keys = protocol.run_keys(config.seed, s, config.runs)
                for c, name in group:
                    missing = sorted(k[3] for k in scene_todo if k[:2] == (c, name))
                    if not missing:
                        continue
                    row = rows[name]
                    if (c, name) not in episodes:
                        episodes[c, name] = _episode(config, row, classifiers[c], object_set, views,
                                                     dataset.scene.split)
                    bar.set_postfix(scene=s, classifier=c, row=name)
                    records = _row_records(config, row, episodes[c, name], views, truth, starts, keys, missing)
                    io.append_jsonl(store, [{"classifier": c, "row": name, "scene": s, **r} for r in records])
                    bar.update(len(records))
            jax.clear_caches()  # the pass's compiled programs (and their memory maps) go
    keep = set(wanted)
    return [r for r in io.read_jsonl(store) if _key(r) in keep]


def _episode(config: Table1Config, row: protocol.Row, classifier: pointnet.Classifier, object_set,
             views: sources.Preloaded, scene_split: str) -> active.Episode:
    base = setup.ActiveConfig(episode=active.EpisodeConfig(decision=config.decision), perception=config.perception,
                              refine=config.refine, nbv=config.nbv)
    return row.episode(base, config.moves, classifier, object_set, views.intrinsics, views.table_height, scene_split)


def _row_records(config: Table1Config, row: protocol.Row, episode: active.Episode, views: sources.Preloaded,
                 truth: scoring.Truth, starts: np.ndarray, keys: jax.Array, runs: list[int]) -> list[dict]:
    """The records of ``runs`` of one row on one scene."""
    if row.kind is protocol.Kind.FULL:
        trace, _ = protocol.all_views(episode, views.depth, views.T_wc, keys[0])
        return [protocol.episode_record(trace, truth, run=0, start=-1)]
    if row.kind is protocol.Kind.ORACLE:
        size = config.oracle_runs_per_call or (1 if jax.default_backend() == "cpu" else len(runs))
        records = []
        for chunk in (runs[i:i + size] for i in range(0, len(runs), size)):
            traces = protocol.oracle_rollouts(episode, views.depth, views.T_wc, starts[chunk], keys[np.asarray(chunk)],
                                              truth)
            records += [protocol.episode_record(jax.tree.map(lambda x, i=i: x[i], traces), truth, run=r,
                                                start=int(starts[r])) for i, r in enumerate(chunk)]
        return records
    # All runs (one compiled shape), brought to the host once.
    traces = jax.device_get(protocol.rollouts(episode, views.depth, views.T_wc, starts, keys))
    return [protocol.episode_record(jax.tree.map(lambda x, r=r: x[r], traces), truth, run=r,
                                    start=int(starts[r])) for r in runs]


def time_modules(config: Table1Config, files: list[Path], dataset: DatasetConfig) -> dict[str, Any]:
    """One VisOcclHistGR episode of the first scene, each module timed outside jit (``runner.run``): the
    median ms per module over its moves after the first, per classifier's weights (the first's)."""
    object_set = object_set_from_config(dataset.objects)
    name, path = next(iter(config.classifiers.items()))
    classifier = setup.load_classifier(path, object_set, f"classifiers.{name}")
    views = sources.dataset_source(files[0], dataset.objects)
    row = protocol.ROWS["vis_occl_hist_gr"]
    episode = _episode(dataclasses.replace(config, moves=config.timing_moves), row, classifier, object_set, views,
                       dataset.scene.split)
    start = int(protocol.start_views(config.seed, 0, 1, len(views.T_wc))[0])
    runner.run(episode, views, start, jax.random.PRNGKey(config.seed))  # compiles
    log = runner.run(episode, views, start, jax.random.PRNGKey(config.seed))
    times = {m: float(np.median([mv["times_ms"][m] for mv in log.moves[1:] or log.moves])) for m in active.MODULES}
    return {"device": report.device_name(), "cpu": report.cpu_name(), "moves": len(log.moves), "times_ms": times}


# --- the table ------------------------------------------------------------------------------------------------

def row_scores(records: list[dict[str, Any]], classes: int, move: int, resamples: int) -> dict[str, Any]:
    """A row's scores after ``move``: each statistic pooled over scenes, F1's 95% scene-bootstrap interval."""
    per_scene = protocol.per_scene(records, move)
    pooled = metrics.classification_scores(np.concatenate([t for t, _ in per_scene]),
                                           np.concatenate([p for _, p in per_scene]), classes)
    _, low, high = metrics.scene_interval(per_scene, classes, "f1", resamples=resamples)
    return {**{k: getattr(pooled, k) for k in STATISTICS}, "f1_low": low, "f1_high": high,
            "scenes": len(per_scene), "episodes": len(records)}


def tables(config: Table1Config, records: list[dict[str, Any]], classes: int, timing: dict | None,
           argv: list[str] | None) -> tuple[str, list[dict[str, Any]], dict[str, dict[str, list]]]:
    """(Markdown, CSV rows, curves for Figure 4) of the stored episodes."""
    T = config.moves
    half = max(1, T // 2)
    by: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        by.setdefault((r["classifier"], r["row"]), []).append(r)
    sections, csv_rows, curves = [], [], {}
    for c in config.classifiers:
        table_rows, notes = [], []
        curves[c] = {}
        for name in config.rows:
            recs = by.get((c, name), [])
            if not recs:
                continue
            row = protocol.ROWS[name]
            moves = T if row.kind in (protocol.Kind.POLICY, protocol.Kind.ORACLE) else 1
            per_move = [row_scores(recs, classes, t, config.resamples) for t in range(1, moves + 1)]
            for t, sc in enumerate(per_move, 1):
                csv_rows.append({"classifier": c, "row": name, "label": row.label, "move": t, **sc})
            curves[c][row.label] = per_move
            last = per_move[-1]
            mid = per_move[min(half, moves) - 1]["f1"]
            steps, right = protocol.moves_to_correct(recs)
            table_rows.append((row.label, *(f"{last[k]:.3f}" for k in STATISTICS),
                               f"[{last['f1_low']:.3f}, {last['f1_high']:.3f}]", f"{mid:.3f}",
                               f"{steps:.2f}" if moves > 1 else "-", f"{right:.2f}", last["scenes"], last["episodes"]))
        notes += _differences(config, by, c, classes)
        sections.append(report.table(
            ("method", "accuracy", "precision", "recall", "F1", "F1 95% CI (scenes)", f"F1 after {half} moves",
             "moves to correct", "share right at the end", "scenes", "episodes"), table_rows))
        sections[-1] = f"#### Classifier `{c}` ({config.classifiers[c] or 'shipped weights'})\n\n" + sections[-1] \
            + ("\n\n" + "\n".join(f"- {n}" for n in notes) if notes else "")
    timing_md = ""
    if timing:
        times = timing["times_ms"]
        timing_md = "\n\n" + report.table(
            ("module", f"ours, ms per move ({timing['device']})", "the paper, ms (i7 desktop)"),
            [(m, f"{times[m]:.1f}", f"{PAPER_TIMES_MS[m]}" if m in PAPER_TIMES_MS else "not given")
             for m in active.MODULES] + [("total", f"{sum(times.values()):.1f}", "1250")])
    intro = (f"{len({r['scene'] for r in records})} scenes of `{config.dataset}`, {config.runs} runs per scene "
             f"from seeded random start views (the same for every row), T = {T}; scores of the target objects "
             f"after move T (PointNetSingle: its one view; PointNetFull: every view fused), pooled over scenes, "
             f"macro over classes; intervals resample whole scenes ({config.resamples} resamples).")
    markdown = (f"### Table 1 on `{config.dataset}`\n\n`{report.command_line(argv)}`\n\n{intro}\n\n"
                + "\n\n".join(sections) + timing_md + "\n")
    return markdown, csv_rows, curves


def _differences(config: Table1Config, by: dict, c: str, classes: int) -> list[str]:
    """Paired scene-bootstrap differences of F1 at T: GR against none per pair; every policy against
    PointNetSingle; VisOcclHist(GR) against Random(GR); every policy against VisOcclHistGR; the oracle
    against the best policy."""
    T, notes = config.moves, []

    def scenes_of(name, move, keep=None):
        return protocol.per_scene([r for r in by.get((c, name), []) if keep is None or r["scene"] in keep], move)

    def diff(a, b, move_a=T, move_b=T):
        # Paired on the scenes both rows have (the oracle runs on fewer; an interrupted run may have more).
        shared = {r["scene"] for r in by[c, a]} & {r["scene"] for r in by[c, b]}
        d, lo, hi = metrics.paired_difference(scenes_of(a, move_a, shared), scenes_of(b, move_b, shared), classes,
                                              resamples=config.resamples)
        sig = "" if lo <= 0 <= hi else " (the interval excludes 0)"
        return f"{protocol.ROWS[a].label} - {protocol.ROWS[b].label}: {d:+.3f} [{lo:+.3f}, {hi:+.3f}]{sig}"

    present = [n for n in config.rows if (c, n) in by]
    policies = [n for n in present if protocol.ROWS[n].kind is protocol.Kind.POLICY]
    for n in present:
        if n.endswith("_gr") and n[:-3] in present:
            notes.append("GR: " + diff(n, n[:-3]))
    for n in policies:
        single = "single_gr" if protocol.ROWS[n].refinement else "single"
        if single in present:
            notes.append("Active at T against one view: " + diff(n, single, T, 1))
    for a, b in (("vis_occl_hist", "random"), ("vis_occl_hist_gr", "random_gr")):  # the paper's VisOcclHist >= Random
        if a in present and b in present:
            notes.append("VisOcclHist against Random: " + diff(a, b))
    if "vis_occl_hist_gr" in present:
        notes += ["Against VisOcclHistGR: " + diff(n, "vis_occl_hist_gr") for n in policies
                  if n != "vis_occl_hist_gr"]
    if "oracle_gr" in present and policies:
        best = max(policies, key=lambda n: metrics.classification_scores(
            *map(np.concatenate, zip(*scenes_of(n, T), strict=True)), classes).f1)
        notes.append("Oracle against the best policy: " + diff("oracle_gr", best))
    return notes


def figure4(curves: dict[str, dict[str, list[dict]]], path: Path) -> None:
    """F1 against moves for every row, with 95% bands: one panel per classifier."""
    figure = viz.score_curves({c: {label: ([s["f1"] for s in v], [s["f1_low"] for s in v], [s["f1_high"] for s in v])
                                   for label, v in rows.items()} for c, rows in curves.items()})
    buffer = _io.BytesIO()
    figure.savefig(buffer, format="png", dpi=120)
    io.write_bytes(path, buffer.getvalue())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_synthetic", help="a path or a shipped config name")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    parser.add_argument("--tables-only", action="store_true",
                        help="only the tables of the episodes stored in out_dir (none run, no scene file read)")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    # No allocator.retain_freed_memory() here: batched episodes gain little from it.
    precision.full_float32_matmuls()  # no TF32 on a GPU (jaxcls.precision)
    compile_cache.enable()  # the row programs kept on disk for the next run (jaxcls.compile_cache)
    config = load_config(Table1Config, args.config, args.overrides)
    out = Path(config.out_dir)
    _check_out_dir(config, out)
    started = time.perf_counter()
    timing_file = out / "timing.json"
    timing = json.loads(timing_file.read_text()) if timing_file.exists() else None
    if args.tables_only:
        dataset = dataset_config(config)
        records = stored_records(config, out / "episodes.jsonl")
    else:
        dataset, files = open_dataset(config)
        save_config(config, out / "config.yaml")
        records = run_episodes(config, files, dataset, out / "episodes.jsonl")
    if timing is None and config.timing_moves and not args.tables_only:
        timing = time_modules(config, files, dataset)
        io.write_json(timing_file, timing)
    classes = len(object_set_from_config(dataset.objects).classes)
    markdown, csv_rows, curves = tables(config, records, classes, timing, argv)
    io.write_text(out / "table.md", markdown)
    buffer = _io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(csv_rows[0]) if csv_rows else ["row"])
    writer.writeheader()
    writer.writerows(csv_rows)
    io.write_text(out / "table.csv", buffer.getvalue())
    if curves:
        figure4(curves, out / "figure4.png")
    print(f"{len(records)} episodes in {out} ({time.perf_counter() - started:.0f} s this run)", file=sys.stderr)
    report.publish(markdown, args.out)


def _check_out_dir(config: Table1Config, out: Path) -> None:
    """An ``out_dir`` holding episodes of another config is refused (its records would mix)."""
    previous = out / "config.yaml"
    if previous.exists() and (out / "episodes.jsonl").exists():
        old = load_config(Table1Config, previous)
        if old.results_defining() != config.results_defining():
            changed = sorted(k for k, v in config.results_defining().items() if old.results_defining().get(k) != v)
            raise ValueError(f"{previous}: out_dir holds episodes of another config (keys {changed} differ); "
                             "choose another out_dir")


if __name__ == "__main__":
    main()
