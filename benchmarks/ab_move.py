"""A/B of one CPU move before and after a refactor, interleaved in one process: this tree's stages and
``perception.observe`` (no classifier: foreground + integration + extraction + ``segment_jax``) against the
stages and the chain wired by hand in an earlier revision of the package (default: 06eb8e1, the last
revision before the layout issue), on the same frames. ``observe`` is timed as called from Python (it runs
its stages' jits one by one) and inside one ``jax.jit``.

    python benchmarks/ab_move.py --rev 06eb8e1 --rounds 15 --repeats 10 --out BENCHMARKS.md

The old revision is exported with ``git archive`` into a temporary folder and imported as ``jaxcls_old``
(its imports renamed), so both run in this process; rounds alternate A and B, and each round's median of
``repeats`` calls is one sample. It also checks that both give the same segments (labels and points).
"""

from __future__ import annotations

import argparse
import datetime
import importlib
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
from jaxcls.perception import foreground, segment, tsdf
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

        # B: this tree: the stages, and the move as its one owner composes it (jitted whole).
        spec = perception.Spec.create(intrinsics=intr, table_height=world.table_height)
        observe = jax.jit(perception.perceive)
        state = perception.init_state(spec)
        for v in range(len(VIEWS) - 1):
            state = observe(spec, state, depth[v], Ts[v])
        d, T = jnp.asarray(depth[-1]), jnp.asarray(Ts[-1])
        fg_new = jax.jit(foreground.foreground_depth)
        integrate_new = jax.jit(lambda vol, d, T: tsdf.integrate(vol, d, intr, T))
        extract_new = jax.jit(lambda vol: tsdf.extract_surface(vol, 16384))
        segment_new = jax.jit(segment.segment_jax)
        surface_new = extract_new(state.volume)

        # A: the earlier revision's stages, and its chain wired as its benchmark wired it.
        cfg = old_segment.SegmentConfig()
        intr_old = old.geometry.Intrinsics(width=intr.width, height=intr.height, fx=intr.fx, fy=intr.fy, cx=intr.cx,
                                           cy=intr.cy)
        fg_old = jax.jit(lambda d, T: old_segment.foreground_depth(d, intr_old, T, cfg))
        integrate_old = jax.jit(lambda vol, d, T: old_tsdf.integrate(vol, d, intr_old, T))
        extract_old = jax.jit(lambda vol: old_tsdf.extract_surface(vol, 16384))
        volume = old_tsdf.create_volume(np.asarray(cfg.roi_center), cfg.roi_size, 128)
        for v in range(len(VIEWS) - 1):
            volume = integrate_old(volume, fg_old(jnp.asarray(depth[v]), jnp.asarray(Ts[v])), jnp.asarray(Ts[v]))
        surface_old = extract_old(volume)

        def old_move():
            s = extract_old(integrate_old(volume, fg_old(d, T), T))
            return old_segment.segment_jax(s.points, s.normals, s.mask, cfg)

        def new_stages():
            s = extract_new(integrate_new(state.volume, fg_new(spec, d, T), T))
            return segment_new(spec, s.points, s.normals, s.mask)

        pairs = {
            "foreground": (lambda: fg_old(d, T), lambda: fg_new(spec, d, T)),
            "integration": (lambda: integrate_old(volume, fg_old(d, T), T),
                            lambda: integrate_new(state.volume, fg_new(spec, d, T), T)),
            "extraction (16384 points)": (lambda: extract_old(volume), lambda: extract_new(state.volume)),
            "segmentation (`segment_jax`)": (
                lambda: old_segment.segment_jax(surface_old.points, surface_old.normals, surface_old.mask, cfg),
                lambda: segment_new(spec, surface_new.points, surface_new.normals, surface_new.mask)),
            "one move, stage by stage": (old_move, new_stages),
            "one move: A stage by stage, B `perception.observe` from Python (no classifier)": (
                old_move, lambda: perception.observe(spec, state, d, T).segments),
            "one move: A stage by stage, B `jax.jit(perception.perceive)` (no classifier)": (
                old_move, lambda: observe(spec, state, d, T).segments),
        }
        a, b = jax.block_until_ready(old_move()), jax.block_until_ready(observe(spec, state, d, T).segments)
        same = all(np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)))
                   for f in ("labels", "points", "normals", "mask"))
        samples = {name: ([], []) for name in pairs}
        for _ in range(args.rounds):
            for name, fns in pairs.items():
                for side, fn in zip(samples[name], fns, strict=True):
                    side.append(report.timed(fn, args.repeats)[1] * 1e3)
        print(samples, file=sys.stderr)

    cpu = report.cpu_name()
    rows = []
    for name, (a_ms, b_ms) in samples.items():
        ratio = [y / x for x, y in zip(a_ms, b_ms, strict=True)]
        rows.append((name, f"{statistics.median(a_ms):.2f}", f"{statistics.median(b_ms):.2f}",
                     f"{statistics.median(ratio):.3f}", f"{min(ratio):.2f} - {max(ratio):.2f}"))
    report.publish(report.section(
        f"One CPU move before and after the layout change, A/B interleaved, {datetime.date.today()}", argv,
        ("640x480 frame, 128^3 volume, N = 5", f"A: {args.rev}, median ms", "B: this tree, median ms",
         "B / A, median of rounds", "B / A, range"), rows,
        intro=f"{cpu}; {args.rounds} alternating rounds, each the median of {args.repeats} calls.",
        notes=[f"A's hand-wired chain and B's `observe` give the same segments (labels, points, normals, "
               f"masks): {same}"]), args.out)


if __name__ == "__main__":
    main()
