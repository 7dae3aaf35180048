"""Counting objects: the share of fused scenes whose estimated number of objects is right, both paths.

    python experiments/counting.py [--seeds 30] [--first-seed 0] [--slots 8] [--tracking reported] [--out RESULTS.md]
    python experiments/counting.py --episodes KNOWN_DIR ESTIMATED_DIR [--moves 1 3 10] [--out RESULTS.md]
    python experiments/counting.py --explain ESTIMATED_DIR [--moves 3 10] [--limit 0] [--json FILE] [--out RESULTS.md]
    python experiments/counting.py --walks [--config table1_synthetic_estimated] [--set KEY=VALUE ...] [--runs 3]
        [--variant NAME:FIELD=VALUE,... ...] [--out RESULTS.md]

Perception with ``perception.shapes.num_objects = estimated`` and ``--slots`` segment slots
(``shapes.num_segments``). Scenes: the builtin set, ``synthetic`` (5 objects, footprint gaps 3 mm - 3 cm),
``touching`` (5 objects, 1-5 mm) and ``mixed`` (1 + seed % 8 objects), seeds 0..n-1, depth from the ``mujoco``
backend at five hemisphere views from low to high elevation, fused into the default 0.6 m / 128^3 volume
through ``perception.observe``; after 1, 3 and 5 views the JAX twin (inside the move) and the reference path
(scikit-learn DBSCAN + SciPy) count the same surface. ``--kinds real_like`` (not a default kind): the
``real_like`` dataset config's scenes (3 targets + 2 clutter; the count to find is all 5) through its sensor
(Kinect-v1 noise, the hand-eye error: frames fused at the poses reported, ``--tracking`` on by default).
``--merge-persistence``, ``--flush-persistence``, ``--flush-height`` and ``--min-object-area`` override
``perception.segmentation``'s.

``--episodes KNOWN_DIR ESTIMATED_DIR``: no scene is fused here; two ``experiments/table1.py`` output folders
whose configs differ only in ``perception.shapes.num_objects`` (``known``, then ``estimated``) and
``num_segments`` are read (their stores) and compared row by row on the episodes both ran: the share of episodes
whose live segment count equals the scene's objects after ``--moves`` (past a row's last move: its last), with a
scene-bootstrap interval, the share of scenes right in every run, the mean absolute count error; and F1 after the
last move with N estimated (each phantom segment a false positive of its class) minus F1 with N given, paired by
scene, with its scene-bootstrap interval. The logic is ``jaxcls.experiments.counting``.

``--explain ESTIMATED_DIR``: why a run with N estimated miscounts. Its episodes whose live segments were not
their objects after one of ``--moves`` are replayed (their recorded views fused again through the run's
perception) and the surface is described against the scene's posed objects (``counting.explain_surface``: each
segment's majority object, area, height, persistence; each object's fate): the table counts the segments that
are not their object's largest (``second``) or belong to no object (``ghost``), by move, touching another
segment or apart on the table, and the class, and the objects without a segment of their own (merged into
another's, dropped, unseen); ``--json`` keeps every description.

``--walks``: for choosing segmentation settings on scenes apart from the evaluation's (``counting.walk_counts``):
the scenes of a Table 1 config (``--config``, ``--set`` its overrides, e.g. a dataset drawn with another seed),
``--runs`` random walks a scene of 10 views within 0.5 m of each other (RandomGR's candidates) fused through its
perception; after moves 1, 3 and 10 the reference path counts each surface under every ``--variant`` (a name,
then ``perception.segmentation`` fields, e.g. ``off:flush_persistence=0.15``).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import time

from jaxcls import perception, report
from jaxcls.experiments import counting
from jaxcls.geometry import Intrinsics
from jaxcls.perception.settings import ObjectCount
from jaxcls.perception.tracking import TrackingConfig


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30, help="scenes per kind (seeds 0..n-1)")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="first seed (settings were chosen on seeds 100-129, disjoint from 0-29)")
    parser.add_argument("--slots", type=int, default=8, help="perception.shapes.num_segments: the most objects")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the Kinect v1 (1 = 640x480)")
    parser.add_argument("--max-points", type=int, default=16384, help="static size of the extracted surface")
    parser.add_argument("--tracking", choices=("frame_to_model", "reported"), default="frame_to_model",
                        help="perception.tracking.mode: register each frame first, or fuse it at the given pose")
    parser.add_argument("--kinds", default=",".join(counting.KINDS),
                        help=f"comma-separated scene kinds of {', '.join(counting.KINDS + counting.REAL_KINDS)}")
    parser.add_argument("--merge-persistence", type=float, help="perception.segmentation.merge_persistence")
    parser.add_argument("--min-object-area", type=float, help="perception.segmentation.min_object_area, m^2")
    parser.add_argument("--flush-persistence", type=float, help="perception.segmentation.flush_persistence")
    parser.add_argument("--flush-height", type=float, help="perception.segmentation.flush_height, m")
    parser.add_argument("--episodes", nargs=2, metavar=("KNOWN_DIR", "ESTIMATED_DIR"),
                        help="compare two Table 1 runs' episodes, N given then N estimated (no scene fused)")
    parser.add_argument("--explain", metavar="ESTIMATED_DIR",
                        help="describe the extra segments of a Table 1 run with N estimated (its episodes replayed)")
    parser.add_argument("--limit", type=int, default=0, help="with --explain: at most this many episodes (0 = all)")
    parser.add_argument("--json", help="with --explain: write every segment's description to this JSON file")
    parser.add_argument("--walks", action="store_true", help="count random walks' surfaces under --variant settings")
    parser.add_argument("--config", default="table1_synthetic_estimated", help="with --walks: the Table 1 config")
    parser.add_argument("--runs", type=int, default=3, help="with --walks: walks a scene")
    parser.add_argument("--variant", nargs="+", default=["default:"], metavar="NAME:FIELD=VALUE,...",
                        help="with --walks: segmentation settings to count with")
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="with --explain: settings laid over the run's config for the replay (e.g. the "
                             "value of a segmentation setting the run was stored without); with --walks: the "
                             "config's overrides")
    parser.add_argument("--moves", type=int, nargs="+",
                        help="with --episodes: the moves after which the counts are read (default 1 3 10); "
                             "with --explain: the moves whose over-counts are explained (default 3 10)")
    parser.add_argument("--resamples", type=int, default=2000, help="with --episodes: bootstrap resamples")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    if args.episodes:
        args.moves = args.moves or list(counting.EPISODE_MOVES)
        compare_episodes(args, argv)
        return
    if args.explain:
        explain(args, argv)
        return
    if args.walks:
        walks(args, argv)
        return
    mode = type(TrackingConfig().mode)(args.tracking)
    seg = perception.SegmentConfig()
    overrides = {k: v for k, v in (("merge_persistence", args.merge_persistence),
                                   ("min_object_area", args.min_object_area),
                                   ("flush_persistence", args.flush_persistence),
                                   ("flush_height", args.flush_height)) if v is not None}
    seg = dataclasses.replace(seg, **overrides)
    settings = perception.PerceptionConfig(
        segmentation=seg, tracking=TrackingConfig(mode=mode),
        shapes=perception.ShapeConfig(surface_points=args.max_points, num_segments=args.slots,
                                      num_objects=ObjectCount.estimated))
    intr = Intrinsics.kinect_v1(args.scale)
    start = time.perf_counter()
    records = counting.counts(args.seeds, args.scale, settings, tuple(args.kinds.split(",")),
                              first_seed=args.first_seed)
    wall = time.perf_counter() - start
    real = [k for k in args.kinds.split(",") if k in counting.REAL_KINDS]
    sensor = (f" {', '.join(real)}: the dataset config's scenes (targets and clutter, all counted) and sensor "
              "(Kinect-v1 noise, one hand-eye error a scene: frames fused at the poses reported); the other kinds: "
              "ideal depth at the poses rendered." if real else "")
    report.publish(report.section(
        f"Counting objects (N estimated), {intr.width}x{intr.height} depth fused into 128^3, {args.seeds} scenes "
        f"per kind (seeds {args.first_seed}-{args.first_seed + args.seeds - 1}), {datetime.date.today()}", argv,
        ("scenes", "views", "path", "n", "N right", "mean abs error", "mean error", "errors (count - objects: scenes)"),
        counting.count_rows(records),
        intro=f"`shapes.num_objects: estimated`, {args.slots} slots, merge_persistence {seg.merge_persistence}, "
              f"flush_persistence {seg.flush_persistence}, flush_height {seg.flush_height} m, min_object_area "
              f"{seg.min_object_area} m^2, absorb_area {seg.absorb_area} m^2; "
              f"tracking {args.tracking}; {wall:.0f} s on the CPU." + sensor),
        args.out)


def walks(args: argparse.Namespace, argv: list[str] | None) -> None:
    """``--walks``: random walks' counts under each ``--variant`` (``counting.walk_counts``), as one table."""
    variants = {}
    for v in args.variant:
        name, _, fields = v.partition(":")
        variants[name] = {k: float(x) for k, x in (f.split("=") for f in fields.split(",") if f)}
    start = time.perf_counter()
    records = counting.walk_counts(args.config, args.set, args.runs, variants)
    wall = time.perf_counter() - start
    scenes = len({r["scene"] for r in records})
    intro = (f"`{args.config}` with {', '.join(args.set) or 'no overrides'}: {scenes} scenes x {args.runs} random "
             "walks of 10 views within 0.5 m of each other, fused through its perception, counted by the reference "
             f"path; variants: {'; '.join(args.variant)}. {wall:.0f} s on the CPU.")
    report.publish(report.section(f"Counting random walks, {datetime.date.today()}", argv,
                                  counting.WALK_HEADER, counting.walk_rows(records), intro=intro), args.out)


def explain(args: argparse.Namespace, argv: list[str] | None) -> None:
    """``--explain``: the over-counted episodes replayed, their extra segments described and summed up."""
    import json

    moves = tuple(args.moves or (3, 10))
    start = time.perf_counter()
    explained = counting.explain_episodes(args.explain, moves, args.limit, overrides=args.set)
    wall = time.perf_counter() - start
    if args.json:
        with open(args.json, "w") as f:
            json.dump(explained, f)
    episodes = len({(e["classifier"], e["row"], e["scene"], e["run"]) for e in explained})
    agree = sum(len(e["segments"]) == e["recorded"] for e in explained)
    laid = f" (replayed with {', '.join(args.set)})" if args.set else ""
    intro = (f"`{args.explain}`{laid}: {episodes} episodes counted other than their objects after move "
             f"{' or '.join(map(str, moves))}; replayed (their views fused again, {wall:.0f} s on the CPU), the "
             f"reference path counts what the episode recorded on {agree} of {len(explained)} surfaces. A segment "
             "is `second` when its points' majority object has a larger segment, `ghost` when most of its "
             "points belong to no object (farther than 1 cm from every posed surface); persistence: the cost of its "
             "cheapest merge (touching: the relative persistence, scaled where flush, < 1; apart on the table: 1 + "
             "its peak / the highest). A missed object has no segment of its own: `merged` (the segment holding "
             "most of its points is another object's), `dropped` (in no live segment), `unseen` (fewer than "
             f"{counting.MISSED_POINTS} surface points).")
    if any(d.get("target") is False for e in explained for d in [*e["segments"], *e["fates"]]):
        intro += (" Clutter (objects never scored, counted all the same): `(clutter)` marks a clutter object's class, "
                  "`merged into clutter` a missed object whose points went to a clutter object's segment.")
    report.publish(report.section(f"Miscounts in Table 1's episodes with N estimated, {datetime.date.today()}",
                                  argv, counting.EXPLAIN_HEADER, counting.explain_rows(explained), intro=intro),
                   args.out)


def compare_episodes(args: argparse.Namespace, argv: list[str] | None) -> None:
    """``--episodes``: the two runs' count and F1 tables (``counting.compare_runs``), published as one section."""
    if any(m < 1 for m in args.moves):
        raise SystemExit(f"--moves: moves are 1-based, got {args.moves}")
    count_rows, f1_rows, facts = counting.compare_runs(*args.episodes, args.moves, args.resamples)
    known, estimated = args.episodes
    intro = (f"Table 1's episodes on `{facts['dataset']}` ({facts['runs']} runs a scene, T = {facts['moves']}): "
             f"`{known}` with N given (`perception.shapes.num_objects: known`, {facts['given_slots']} segments), "
             f"`{estimated}` with N estimated (`estimated`, at most {facts['slots']} segments); the episodes both "
             "ran, paired by (scene, run). A count is the episode's live segments after the move; scenes right in "
             "every run: every run of the scene counted its objects. F1 after move T; phantoms counted: each "
             "live segment matched to no object is a false positive of its refined class. Differences are paired "
             f"by scene, 95% intervals resample whole scenes ({args.resamples} resamples).")
    markdown = report.section(f"N given against N estimated in Table 1's episodes, {datetime.date.today()}", argv,
                              counting.COUNT_HEADER, count_rows, intro=intro)
    markdown += "\n" + report.table(counting.F1_HEADER, f1_rows) + "\n"
    report.publish(markdown, args.out)


if __name__ == "__main__":
    main()
