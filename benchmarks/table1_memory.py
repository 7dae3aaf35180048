"""Will a Table 1 config fit a GPU? XLA's memory analysis of its two largest programs, compiled for this machine's
backend (on a CPU an estimate of a GPU's: the fusions differ), with an untrained classifier of the set's classes
(the memory does not depend on the weights):

    python benchmarks/table1_memory.py --config table1_hard [--oracle-runs 32] [--batch 100] [overrides ...]

- the oracle's call (``protocol.oracle_rollouts``' move program: ``oracle_runs_per_call`` runs x the episode's
  candidates, each a whole move from its own state, the states out), with 4 scenes' frames in;
- a batched row (VisOcclHistGR's ``active.rollout`` vmapped over ``--batch`` episodes of one scene): per episode,
  what a call of ``scene_chunk`` x ``runs`` episodes needs besides its frames (123 MB a scene at 640x480).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

from jaxcls.config import load_config
from jaxcls.episode import active, protocol
from jaxcls.experiments.table1 import data, runner
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.perception import pointnet
from jaxcls.world.objects import object_set_from_config


def gigabytes(analysis) -> tuple[float, float, float]:
    """(temporaries, outputs, arguments) GB of a compiled program's ``memory_analysis``."""
    return tuple(x / 1e9 for x in (analysis.temp_size_in_bytes, analysis.output_size_in_bytes,
                                    analysis.argument_size_in_bytes))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_hard")
    parser.add_argument("--oracle-runs", type=int, help="runs a call (default: the config's oracle_runs_per_call)")
    parser.add_argument("--batch", type=int, default=100, help="episodes of the batched row's program")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    config = load_config(Table1Config, args.config, ['classifiers={any: ""}', *args.overrides])
    dataset = data.dataset_config(config)
    object_set = object_set_from_config(dataset.objects)
    classes = tuple(object_set.classes)
    model = pointnet.ModelConfig(yaw_head=True)
    classifier = pointnet.Classifier(pointnet.init_variables(jax.random.key(0), len(classes), model), classes, model,
                                     yaw_orders=(0,) * len(classes))
    intrinsics = dataset.camera.intrinsics()

    def episode(row: str) -> active.Episode:
        return runner.episode(config, protocol.ROWS[row], classifier, object_set, intrinsics,
                              dataset.scene.table_height, dataset.scene.split, name="any")

    S, V = 4, 100
    frames = jax.ShapeDtypeStruct((S, V, intrinsics.height, intrinsics.width), jnp.float32)
    T_wc = jnp.tile(jnp.eye(4, dtype=jnp.float32), (S, V, 1, 1)).at[..., 2, 3].set(1.0)
    print(f"{args.config} {' '.join(args.overrides)}: volume {config.perception.volume}", flush=True)
    R = args.oracle_runs or config.oracle_runs_per_call or runner.ORACLE_EPISODES_PER_CALL
    oracle = episode("oracle_gr")
    at = jnp.zeros(R, jnp.int32)
    states = jax.eval_shape(protocol._resets, oracle, T_wc[at], at, jax.random.split(jax.random.key(0), R))
    C = oracle.nbv_config.max_candidates
    t0 = time.perf_counter()
    compiled = protocol._runs_moves_to.lower(oracle, states, frames, T_wc, at,
                                             jax.ShapeDtypeStruct((R, C), jnp.int32)).compile()
    temp, out, arg = gigabytes(compiled.memory_analysis())
    print(f"the oracle, {R} runs x {C} candidates a call: {temp + out + arg:.1f} GB (temporaries {temp:.1f}, "
          f"states out {out:.1f}, in {arg:.1f}; compiled in {time.perf_counter() - t0:.0f} s)", flush=True)
    row = episode("vis_occl_hist_gr")
    B = args.batch
    states = jax.eval_shape(jax.vmap(active.reset, in_axes=(None, None, 0, 0)), row, T_wc[0], jnp.zeros(B, jnp.int32),
                            jax.random.split(jax.random.key(0), B))
    rollout = jax.jit(jax.vmap(active.rollout, in_axes=(None, 0, None, None)))
    temp, out, arg = gigabytes(rollout.lower(row, states, frames.update(shape=frames.shape[1:]), T_wc[0])
                               .compile().memory_analysis())
    episodes = config.scene_chunk * config.runs
    print(f"a batched row, {B} episodes: {1e3 * (temp + out) / B:.0f} MB an episode (temporaries and traces): a call "
          f"of {episodes} episodes ~{(temp + out) / B * episodes:.1f} GB besides {config.scene_chunk} scenes' frames",
          flush=True)


if __name__ == "__main__":
    main()
