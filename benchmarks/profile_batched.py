"""Where a batched move's GPU time goes, kernel by kernel: a ``jax.profiler`` trace of Table 1's program
(``episode.batched``) at B episodes of one scene, each kernel attributed to the stage and function that issued
it through XLA's op names (the move's stages run under ``jax.named_scope``; jitted functions add their names).

    python benchmarks/episode_batched.py --save data/gpu/scene3.npz      # frames of one scene (needs MuJoCo)
    python benchmarks/profile_batched.py --frames data/gpu/scene3.npz --batch 512 --keep runs/profile [--out ...]
    python benchmarks/profile_batched.py --analyse runs/profile/trace.json.gz runs/profile/hlo.txt[.xz]

Run mode traces one call (after a first, compiling call) with CUDA graphs off (a graph's kernels carry its
name, not theirs) and XLA's optimized HLO dumped, then analyses both; ``--keep`` keeps the two files.
``--analyse`` attributes a kept trace: per stage and per function, the kernels' summed time and share.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import lzma
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

# Where each named jit belongs when the trace predates the stages' scopes (or a kernel sits outside them).
FUNCTION_STAGE = {"_track_jit": "reconstruction", "_integrate": "reconstruction", "extract_surface": "reconstruction",
                  "foreground_depth": "reconstruction", "segment_jax": "segmentation", "predict": "classification"}
STAGES = ("arrive", "reconstruction", "segmentation", "classification", "refinement", "planning")
_INSTRUCTION = re.compile(r'^\s*(?:ROOT )?%?([\w.\-]+) = .*?metadata=\{[^}]*op_name="([^"]*)"')


def op_names(hlo_text: str) -> dict[str, str]:
    """{HLO instruction name: its op name (the JAX name stack)} of an optimized HLO module's text."""
    return {m.group(1): m.group(2) for m in map(_INSTRUCTION.match, hlo_text.splitlines()) if m}


def attribute(trace_path: str | Path, hlo_path: str | Path) -> tuple[float, list[tuple[str, str, float]]]:
    """(total kernel ms, [(stage, function, ms)] sorted by ms) of the GPU kernels in a perfetto trace
    (``jax.profiler.trace(..., create_perfetto_trace=True)``), by the op names of the HLO they ran."""
    opener = lzma.open if str(hlo_path).endswith(".xz") else open
    with opener(hlo_path, "rt") as f:
        names = op_names(f.read())
    with gzip.open(trace_path, "rt") as f:
        events = json.load(f)["traceEvents"]
    devices = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
               and "/device:GPU" in e["args"]["name"]}
    times: collections.Counter = collections.Counter()
    for e in events:
        if e.get("ph") != "X" or e["pid"] not in devices:
            continue
        name = names.get(e.get("args", {}).get("hlo_op", ""), "")
        parts = name.split("/")
        stage = next((p for p in parts if p in STAGES), None)
        jits = re.findall(r"jit\(([^)]*)\)", name)
        jits = [j for j in jits if j != jits[0]]  # below the program's own jit (named once or twice)
        function = jits[0] if jits else "(no named function)"
        stage = stage or FUNCTION_STAGE.get(function, "(no stage name)")
        times[stage, function] += e["dur"] / 1e3
    total = sum(times.values())
    return total, sorted(((s, f, ms) for (s, f), ms in times.items()), key=lambda r: -r[2])


def table_rows(total: float, rows: list[tuple[str, str, float]], moves: int) -> list[tuple]:
    """Per stage (its functions' sum first), then per function: ms, share, us per move."""
    stages: collections.Counter = collections.Counter()
    for stage, _, ms in rows:
        stages[stage] += ms
    out = []
    for stage, ms in stages.most_common():
        out.append((f"**{stage}**", "all", f"{ms:.1f}", f"{100 * ms / total:.1f}%", f"{1e3 * ms / moves:.1f}"))
        out += [("", function, f"{fms:.1f}", f"{100 * fms / total:.1f}%", f"{1e3 * fms / moves:.1f}")
                for s, function, fms in rows if s == stage and fms >= 0.01 * total]
    return out


def trace_program(frames: str, batch: int, moves: int, workdir: Path,
                  product: str = "bfloat16") -> tuple[Path, Path, float, str]:
    """Trace one call of Table 1's program at ``batch`` episodes of the scene in ``frames``, with the real-like
    scale config's perception (``table1_real_like_scale``), PointNet's products in ``product``
    (``perception.classification_precision``); returns (trace, HLO, untraced moves/s, device)."""
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + f" --xla_dump_to={workdir / 'dump'} "
                               "--xla_dump_hlo_as_text --xla_dump_hlo_module_re=jit__one "
                               "--xla_gpu_enable_command_buffer=")
    import dataclasses

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxcls import precision, report
    from jaxcls.config import load_config
    from jaxcls.episode import active, batched, setup
    from jaxcls.experiments.table1.config import Table1Config
    from jaxcls.geometry import Intrinsics
    from jaxcls.world.objects import object_set_from_config
    from jaxcls.world.scenes import Scene

    precision.full_float32_matmuls()
    with np.load(frames) as f:
        depth = jnp.asarray(f["depth_mm"].astype(np.float32) / 1000.0)[None]
        T_wc = jnp.asarray(f["T_wc"], jnp.float32)[None]
        scene = Scene.from_dict(json.loads(str(f["scene_json"])), source=frames)
    # The real-like scale config's perception (its layout, tracking and kernels), PointNet's products in `product`
    perception = dataclasses.replace(load_config(Table1Config, "table1_real_like_scale", []).perception,
                                     classification_precision=product)
    episode = setup.make_episode(setup.ActiveConfig(episode=active.EpisodeConfig(moves=moves), perception=perception),
                                 object_set_from_config(scene.object_set), Intrinsics.kinect_v1(), scene.table_height)
    scenes = np.zeros(batch, np.int32)
    starts = np.random.default_rng(batch).integers(0, T_wc.shape[1], batch).astype(np.int32)
    keys = jax.random.split(jax.random.PRNGKey(batch), batch)
    mesh = batched.mesh(jax.local_devices()[:1])

    def call():
        return jax.block_until_ready(batched.dispatch(episode, depth, T_wc, scenes, starts, keys, mesh))

    call()  # compiles
    t0 = time.perf_counter()
    call()
    rate = batch * moves / (time.perf_counter() - t0)
    with jax.profiler.trace(str(workdir / "trace"), create_perfetto_trace=True):
        call()
    trace = next((workdir / "trace").rglob("*.json.gz"))
    hlo = max((workdir / "dump").glob("*jit__one*after_optimizations.txt"), key=lambda p: p.stat().st_size)
    return trace, hlo, rate, report.device_name()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="data/gpu/scene3.npz")
    parser.add_argument("--batch", type=int, default=512)
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--keep", help="keep the trace and the HLO in this folder")
    parser.add_argument("--analyse", nargs=2, metavar=("TRACE", "HLO"), help="attribute a kept trace; run nothing")
    parser.add_argument("--precision", default="bfloat16", choices=["float32", "tf32", "bfloat16"],
                        help="perception.classification_precision (the scale configs': bfloat16)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    from jaxcls import report

    if args.analyse:
        trace, hlo = map(Path, args.analyse)
        intro = f"The kept trace {trace} and HLO {hlo}; {args.batch} episodes x {args.moves} moves assumed."
    else:
        work = Path(tempfile.mkdtemp(prefix="profile_batched_"))
        trace, hlo, rate, device = trace_program(args.frames, args.batch, args.moves, work, args.precision)
        if args.keep:
            Path(args.keep).mkdir(parents=True, exist_ok=True)
            trace, hlo = shutil.copy(trace, args.keep), shutil.copy(hlo, args.keep)
        intro = (f"{device}: Table 1's program at {args.batch} episodes x {args.moves} moves of {args.frames}, "
                 f"PointNet {args.precision}, {rate:.0f} moves/s untraced; one traced call, CUDA graphs off.")
    total, rows = attribute(trace, hlo)
    moves = args.batch * args.moves
    report.publish(report.section(
        "Where a batched move's GPU time goes", argv, ("stage", "function", "kernel ms a call", "share",
                                                       "kernel us a move"),
        table_rows(total, rows, moves), intro=f"{intro} Kernel time {total:.0f} ms a call."), args.out)


if __name__ == "__main__":
    main()
