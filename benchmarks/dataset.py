"""Rendering a whole dataset in one process against ``workers`` processes (``jaxcls dataset workers=N``).

    python benchmarks/dataset.py --config real_like --scenes 4 --workers 2 [--rounds 2] [--out BENCHMARKS.md]

Each round renders the same ``--scenes`` scenes into a fresh folder once with ``workers=1`` and once with
``workers=N`` (A/B interleaved, the order alternating by round), CPU renderer (``backend=mujoco``) and the
config's sensor model. The files are checked equal (the parallel run writes what one process writes).
Reports the median wall time over rounds, the spread, and scenes per second.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from jaxcls import report
from jaxcls.config import load_config, save_config
from jaxcls.world.dataset import DatasetConfig, SceneViews, build_dataset, scene_file


def _render(config: DatasetConfig, workers: int, folder: Path) -> float:
    start = time.perf_counter()
    build_dataset(load_config(DatasetConfig, config, [f"workers={workers}", f"out_dir={folder}"]),
                  show_progress=False)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="real_like", help="a dataset config (shipped name or path)")
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", help="append the section to this Markdown file")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    if args.scenes < 1 or args.workers < 2 or args.rounds < 1:
        raise ValueError(f"--scenes >= 1, --workers >= 2, --rounds >= 1 (got {args.scenes}, {args.workers}, "
                         f"{args.rounds})")
    base = load_config(DatasetConfig, args.config, [*args.overrides, f"num_scenes={args.scenes}", "backend=mujoco"])
    times: dict[int, list[float]] = {1: [], args.workers: []}
    with tempfile.TemporaryDirectory() as tmp:
        config_file = Path(tmp) / "config.yaml"
        save_config(base, config_file)
        for r in range(args.rounds):
            order = (1, args.workers) if r % 2 == 0 else (args.workers, 1)
            for workers in order:
                folder = Path(tmp) / f"r{r}_w{workers}"
                times[workers].append(_render(config_file, workers, folder))
            for i in range(args.scenes):
                one, many = (SceneViews.load(scene_file(Path(tmp) / f"r{r}_w{w}", i)) for w in (1, args.workers))
                if not (np.array_equal(one.depth, many.depth) and np.array_equal(one.T_wc, many.T_wc)):
                    raise AssertionError(f"round {r}, scene {i}: workers={args.workers} wrote other frames")
    rows = []
    for workers, t in times.items():
        median = float(np.median(t))
        rows.append((workers, f"{median:.1f}", f"{min(t):.1f}-{max(t):.1f}", f"{args.scenes / median:.2f}",
                     f"{np.median(times[1]) / median:.2f}x"))
    view_count = base.viewpoints.count
    report.publish(report.section(
        f"Rendering {args.scenes} `{args.config}` scenes x {view_count} views, one process against "
        f"{args.workers}, {report.cpu_name()}", argv,
        ("workers", "wall s (median)", "range", "scenes/s", "speed-up"), rows,
        intro=f"{args.rounds} rounds, A/B interleaved; the files of both are equal."), args.out)


if __name__ == "__main__":
    main()
