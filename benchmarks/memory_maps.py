"""Memory maps per compiled program, compile time and run time, with XLA's defaults and with jaxcls's XLA
flags (``jaxcls.xla_flags.FLAGS``).

    python benchmarks/memory_maps.py [--programs 20] [--rounds 2] [--no-episode] [--setting NAME=FLAGS]
        [--only NAME] [--out FILE]

Each (setting, round) is a fresh process (``JAXCLS_XLA_FLAGS=off``, ``$XLA_FLAGS`` set to the setting's
flags, the persistent compilation cache off); rounds alternate the order of the settings. In it:

- ``--programs`` distinct jitted programs of realistic size (a point cloud centred, sorted by distance,
  its cumulative sum, a scatter into a grid, a product, a gather, a small scanned loop: ~50-100 kernels
  each), each kept alive: new lines of ``/proc/self/maps`` per program, XLA compile seconds per program
  (JAX's backend-compile events);
- the episode at the test sizes (``tests/test_episode.py``: 3 objects, 40 viewpoints, 8192 surface points,
  256 points a segment): ``active.step_jit`` (one program per move) and ``active.timed_step`` (one program
  per stage, ``jaxcls run``'s path): maps, compile seconds and the median of 4 later moves.

``--setting`` adds a setting (e.g. jaxcls's flags with XLA's lowest optimisation, ``--xla_backend_optimization_level=0
--xla_llvm_disable_expensive_passes=true``: what ``jax_disable_most_optimizations`` sets, the test suite's level);
``--only`` keeps the named settings alone (repeatable; the first named is the reference of the states).
Reported: the median over rounds. Every run's states after the same moves are compared with the first
setting's: the flags change the code generator of the fused loops, hence float rounding, not the labels.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

SETTINGS = {
    "XLA defaults": "",
    "fusion emitters off": "--xla_cpu_use_fusion_emitters=false",
}


def _settings() -> dict[str, str]:
    from jaxcls import xla_flags

    return {**SETTINGS, "jaxcls (xla_flags.FLAGS)": " ".join(f"--{k}={v}" for k, v in xla_flags.FLAGS.items())}


def _child(programs: int, episode: bool, states: str) -> dict:
    import dataclasses
    import time

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxcls import xla_flags

    compile_s: list[float] = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, secs, **kw: compile_s.append(secs) if "backend_compile" in name else None)
    out: dict = {"xla_flags": os.environ.get("XLA_FLAGS", "")}

    def measured(fn):
        compile_s.clear()
        before = xla_flags.count_maps()
        start = time.perf_counter()
        result = jax.block_until_ready(fn())
        return result, xla_flags.count_maps() - before, sum(compile_s), time.perf_counter() - start

    def make(i: int):
        def program(points, index):
            d = points - points.mean(0) * (1.0 + 1e-3 * i)
            n = jnp.sqrt((d * d).sum(1) + 1e-12)
            order = jnp.argsort(n)
            ranked = jnp.cumsum(n[order]) / (n.sum() + 1.0)
            grid = jnp.zeros((64, 64)).at[index % 64, (index // 64) % 64].add(n)
            mixed = jnp.tanh(grid @ grid.T * 1e-3) + jnp.cumsum(grid, 1).max(0)
            picked = mixed[index % 64][:, :3] * d

            def body(c, _):
                c = jnp.tanh(c @ jnp.eye(3) * (1.0 + i) + picked[:8].sum(0))
                return c, c.sum()

            c, trace = jax.lax.scan(body, picked[:8], None, length=3)
            return ranked[-1] + c.sum() + trace.sum() + jnp.median(picked, 0).sum()
        return jax.jit(program)

    key = jax.random.PRNGKey(0)
    points = jax.random.normal(key, (4096, 3))
    index = jax.random.randint(key, (4096,), 0, 4096)
    jax.block_until_ready(make(-1)(points, index))  # JAX's own first-use programs out of the count
    kept, maps, secs = [], [], []
    for i in range(programs):
        f = make(i)
        kept.append(f)
        _, m, c, _ = measured(lambda f=f: f(points, index))
        maps.append(m)
        secs.append(c)
    out["programs"] = {"maps": statistics.mean(maps), "compile_s": statistics.mean(secs)}

    if episode:
        from jaxcls.episode import active, setup
        from jaxcls.geometry import CameraConfig
        from jaxcls.perception.settings import PerceptionConfig, ShapeConfig
        from jaxcls.world.scenes import SceneConfig
        from jaxcls.world.setup import WorldConfig, make_world

        world = make_world(WorldConfig(camera=CameraConfig.kinect_v1(0.5), scene=SceneConfig(num_objects=3),
                                       backend="mujoco",
                                       viewpoints=dataclasses.replace(WorldConfig().viewpoints, count=40)), seed=1)
        depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(0), np.arange(len(world.viewpoints)))
        T_wc = np.asarray(T_wc, np.float32)
        shapes = ShapeConfig(surface_points=8192, points_per_segment=256)
        ep = setup.make_episode(setup.ActiveConfig(episode=active.EpisodeConfig(moves=6),
                                                   perception=PerceptionConfig(shapes=shapes)),
                                world.object_set, world.intrinsics, world.table_height)
        start = jax.block_until_ready(active.reset(ep, world.viewpoints, 7, jax.random.PRNGKey(0)))
        views = (7, 3, 12, 25, 31)
        for name, move in (("step_jit", lambda s, v: active.step_jit(ep, s, depth[v], T_wc[v])),
                           ("timed_step", lambda s, v: active.timed_step(ep, s, depth[v], T_wc[v])[0])):
            state, m, c, _ = measured(lambda move=move: move(start, views[0]))
            runs = []
            for v in views[1:]:
                t = time.perf_counter()
                state = jax.block_until_ready(move(state, v))
                runs.append(time.perf_counter() - t)
            out[name] = {"maps": m, "compile_s": c, "move_ms": 1000 * statistics.median(runs)}
            np.savez(f"{states}_{name}.npz", **{jax.tree_util.keystr(path): np.asarray(leaf)
                                                for path, leaf in jax.tree_util.tree_leaves_with_path(state)})
    return out


def _same_state(a: str, b: str) -> str:
    import numpy as np

    x, y = np.load(a), np.load(b)
    worst, where = 0.0, ""
    for k in x.files:
        if x[k].dtype.kind in "biu":
            if not np.array_equal(x[k], y[k]):
                return f"integers differ ({k})"
        elif x[k].size:
            diff = float(np.nanmax(np.abs(x[k].astype(np.float64) - y[k].astype(np.float64))))
            worst, where = max((worst, where), (diff, k))
    return f"integers equal, floats within {worst:.1e}" + (f" ({where})" if worst else "")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--programs", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--no-episode", action="store_true")
    parser.add_argument("--setting", action="append", default=[], metavar="NAME=FLAGS",
                        help="another setting to measure (repeatable)")
    parser.add_argument("--only", action="append", default=[], metavar="NAME",
                        help="measure only these settings (repeatable), in this order")
    parser.add_argument("--out", help="append the section to this Markdown file")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print("RESULT " + json.dumps(_child(args.programs, not args.no_episode, args.child)))
        return

    import tempfile

    from jaxcls import compile_cache, report

    settings = _settings()
    settings.update(dict(spec.split("=", 1) for spec in args.setting))
    if args.only:
        if unknown := [name for name in args.only if name not in settings]:
            parser.error(f"--only: no setting named {unknown}; the settings: {list(settings)}")
        settings = {name: settings[name] for name in args.only}
    runs: dict[str, list[dict]] = {name: [] for name in settings}
    same: dict[str, set[str]] = {name: set() for name in settings}
    with tempfile.TemporaryDirectory() as tmp:
        first_states = None
        for r in range(args.rounds):
            order = list(settings) if r % 2 == 0 else list(settings)[::-1]
            for name in order:
                states = str(Path(tmp) / f"state_{len(runs[name])}_{list(settings).index(name)}")
                env = {**os.environ, "XLA_FLAGS": settings[name], "JAXCLS_XLA_FLAGS": "off",
                       compile_cache.ENV: "off"}
                cmd = [sys.executable, __file__, "--child", states, "--programs", str(args.programs)]
                done = subprocess.run(cmd + (["--no-episode"] if args.no_episode else []), env=env,
                                      capture_output=True, text=True)
                if done.returncode != 0:
                    raise RuntimeError(f"{name}: child failed ({done.returncode}): {done.stderr[-3000:]}")
                result = json.loads(next(line for line in done.stdout.splitlines() if line.startswith("RESULT "))[7:])
                runs[name].append(result)
                print(name, r, json.dumps(result), file=sys.stderr, flush=True)
                if not args.no_episode:
                    first_states = first_states or states
                    same[name].add(_same_state(f"{first_states}_step_jit.npz", f"{states}_step_jit.npz"))

    def med(name: str, part: str, field: str, fmt: str) -> str:
        values = [run[part][field] for run in runs[name] if part in run]
        return format(statistics.median(values), fmt) if values else "-"

    rows = []
    for name, flags in settings.items():
        row = [name, f"`{flags}`" if flags else "(none)", med(name, "programs", "maps", ".0f"),
               med(name, "programs", "compile_s", ".2f")]
        if not args.no_episode:
            row += [med(name, "step_jit", "maps", ".0f"), med(name, "step_jit", "compile_s", ".1f"),
                    med(name, "step_jit", "move_ms", ".0f"), med(name, "timed_step", "maps", ".0f"),
                    med(name, "timed_step", "compile_s", ".1f"), med(name, "timed_step", "move_ms", ".0f")]
        rows.append(row)
    header = ["setting", "XLA_FLAGS", "maps / program", "compile s / program"]
    if not args.no_episode:
        header += ["step_jit maps", "compile s", "move ms", "timed_step maps", "compile s", "move ms"]
    notes = [f"{args.programs} distinct programs per process; medians of {args.rounds} rounds, each setting a "
             "fresh process"]
    if not args.no_episode:
        notes += [f"{name}: episode state after 5 moves vs the first run: {'; '.join(sorted(s))}"
                  for name, s in same.items()]
    report.publish(report.section(f"Memory maps per compiled program, {report.cpu_name()}", argv, header, rows,
                                  notes=notes), args.out)


if __name__ == "__main__":
    main()
