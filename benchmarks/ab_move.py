"""A/B of one CPU move before and after a refactor, interleaved in one process: this tree's
``perception.observe`` (no classifier: foreground + integration + extraction + ``segment_jax``) against the
same chain wired by hand in an earlier revision of the package (default: 06eb8e1, the last revision before
the layout issue), on the same frames.

    python benchmarks/ab_move.py --rev 06eb8e1 --rounds 15 --repeats 10 --out BENCHMARKS.md

The old revision is exported with ``git archive`` into a temporary folder and imported as ``jaxcls_old``
(its imports renamed), so both run in this process; rounds alternate A and B, and each round's median of
``repeats`` calls is one sample. It also checks that both give the same segments (labels and points).
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import os
import platform
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import perception, report
from jaxcls.geometry import CameraConfig
from jaxcls.world.setup import WorldConfig, make_world

ROOT = Path(__file__).resolve().parent.parent
VIEWS = (20, 35, 50, 65, 80)


def import_revision(rev: str, folder: Path):
    """The package as it was at ``rev``, importable as ``jaxcls_old``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "jaxcls"], check=True, capture_output=True).stdout
    tar_path = folder / "old.tar"
    tar_path.write_bytes(archive)
    with tarfile.open(tar_path) as tar:
        tar.extractall(folder, filter="data")
    (folder / "jaxcls").rename(folder / "jaxcls_old")
    for path in (folder / "jaxcls_old").rglob("*.py"):
        path.write_text(re.sub(r"\bjaxcls\b", "jaxcls_old", path.read_text()))
    sys.path.insert(0, str(folder))
    return importlib.import_module("jaxcls_old")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", default="06eb8e1", help="the earlier revision (git) to compare against")
    parser.add_argument("--rounds", type=int, default=15, help="alternating A/B rounds")
    parser.add_argument("--repeats", type=int, default=10, help="calls per round (their median is one sample)")
    parser.add_argument("--out", help="append the section to this Markdown file")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        old = import_revision(args.rev, Path(tmp))
        old_segment = importlib.import_module("jaxcls_old.segment")
        old_tsdf = importlib.import_module("jaxcls_old.tsdf")

        world = make_world(WorldConfig(camera=CameraConfig(), backend="mujoco"), seed=0)
        frames = world.render(list(VIEWS))
        depth, Ts = np.asarray(frames.depth), np.asarray(world.poses(list(VIEWS)), np.float32)
        intr = world.intrinsics

        # B: this tree, one owner.
        spec = perception.Spec.create(intrinsics=intr, table_height=world.table_height)
        observe = jax.jit(perception.observe)
        state = perception.init_state(spec)
        for v in range(len(VIEWS) - 1):
            state = observe(spec, state, depth[v], Ts[v])
        d, T = jnp.asarray(depth[-1]), jnp.asarray(Ts[-1])

        def new_move():
            return observe(spec, state, d, T).segments

        # A: the earlier revision's chain, wired as its benchmark wired it.
        cfg = old_segment.SegmentConfig()
        fg_fn = jax.jit(lambda d, T: old_segment.foreground_depth(d, intr_old, T, cfg))
        intr_old = old.geometry.Intrinsics(width=intr.width, height=intr.height, fx=intr.fx, fy=intr.fy, cx=intr.cx,
                                           cy=intr.cy)
        integrate = jax.jit(lambda vol, d, T: old_tsdf.integrate(vol, d, intr_old, T))
        extract = jax.jit(lambda vol: old_tsdf.extract_surface(vol, 16384))
        volume = old_tsdf.create_volume(np.asarray(cfg.roi_center), cfg.roi_size, 128)
        for v in range(len(VIEWS) - 1):
            volume = integrate(volume, fg_fn(jnp.asarray(depth[v]), jnp.asarray(Ts[v])), jnp.asarray(Ts[v]))

        def old_move():
            s = extract(integrate(volume, fg_fn(d, T), T))
            return old_segment.segment_jax(s.points, s.normals, s.mask, cfg)

        a, b = jax.block_until_ready(old_move()), jax.block_until_ready(new_move())
        same = all(np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)))
                   for f in ("labels", "points", "normals", "mask"))
        samples: dict[str, list[float]] = {"A": [], "B": []}
        for _ in range(args.rounds):
            for name, fn in (("A", old_move), ("B", new_move)):
                samples[name].append(report.timed(fn, args.repeats)[1] * 1e3)
        print(samples, file=sys.stderr)

    cpu = f"CPU ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)"
    rows = [(f"A: revision {args.rev}, chain wired by hand", cpu, f"{statistics.median(samples['A']):.1f}",
             f"{min(samples['A']):.1f} - {max(samples['A']):.1f}"),
            ("B: this tree, `perception.observe` (no classifier)", cpu, f"{statistics.median(samples['B']):.1f}",
             f"{min(samples['B']):.1f} - {max(samples['B']):.1f}")]
    ratio = [x / y for x, y in zip(samples["B"], samples["A"], strict=True)]
    report.publish(report.section(
        f"One CPU move before and after the layout change, A/B interleaved, {datetime.date.today()}", argv,
        ("move (640x480, 128^3, 16384 surface points, N = 5)", "device",
         f"median ms ({args.rounds} rounds x median of {args.repeats})", "range over rounds"), rows,
        notes=[f"B / A per round: median {statistics.median(ratio):.3f}, range {min(ratio):.3f} - {max(ratio):.3f}",
               f"same segments (labels, points, normals, masks): {same}"]), args.out)


if __name__ == "__main__":
    main()
