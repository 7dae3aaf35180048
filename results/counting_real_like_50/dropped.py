"""Why an object seen by the estimated-count segmentation ends in no segment (``--explain``'s ``missed: dropped``).

    python results/counting_real_like_50/dropped.py RUN_DIR EXPLAIN.json

For each dropped object of ``EXPLAIN.json`` (``experiments/counting.py --explain RUN_DIR --json EXPLAIN.json``) its
episode's views up to that move are fused again through the run's perception and the reference path's parts
(``segment.reference._watershed_reference``, after the merge) holding the object's points are listed: their
footprint area (cm^2), whether under ``min_object_area`` (then dropped), the cost of their cheapest merge (< 1:
touching another part, the relative persistence; >= 1: apart on the table), and the object's points DBSCAN calls
noise. Prints one line an object, then a summary.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def main(run_dir: Path, explained: Path) -> None:
    import jax
    import jax.numpy as jnp

    from jaxcls import metrics, perception
    from jaxcls.config import load_config
    from jaxcls.experiments.table1 import data
    from jaxcls.experiments.table1.config import Table1Config
    from jaxcls.perception import observation
    from jaxcls.perception.foreground import foreground_mask
    from jaxcls.perception.segment import common, reference
    from jaxcls.world.scenes import scene_models

    config = load_config(Table1Config, run_dir / "config.yaml")
    records = {(r["classifier"], r["row"], r["scene"], r["run"]): r
               for r in data.stored_records(config, run_dir / "episodes.jsonl")}
    _, scene_set = data.open_scenes(config)
    reconstruct = jax.jit(observation.reconstruct)
    cell = config.perception.segmentation.footprint_cell
    found = []
    for e in json.loads(explained.read_text()):
        for o in e["fates"]:
            if o["fate"] != "dropped":
                continue
            r = records[(e["classifier"], e["row"], e["scene"], e["run"])]
            frames = scene_set.load([e["scene"]])[0]
            owners = metrics.PointOwners(frames.scene, scene_models(frames.scene))
            spec = perception.Spec.create(config.perception, frames.intrinsics, frames.table_height)
            state = perception.init_state(spec)
            for view in r["path"][:e["move"]]:
                depth, T = frames.frame(view)
                state = reconstruct(spec, state, jnp.asarray(depth, jnp.float32), jnp.asarray(T, jnp.float32))
            s = state.surface
            p, n, m = np.asarray(s.points), np.asarray(s.normals), np.asarray(s.mask)
            own = owners(p, m)
            fg = np.asarray(foreground_mask(spec, jnp.asarray(p), jnp.asarray(m)))
            x, nn, ow = p[fg].astype(np.float64), n[fg].astype(np.float64), own[fg]
            parts = reference._watershed_reference(spec, x, nn)
            merged = parts.merged
            cost, _ = common._merge_costs(np, merged, parts.peak, common._count_rule(spec))
            small = common._too_small(merged, spec)
            group = np.full(len(x), -1)
            group[parts.good] = parts.group
            mine = ow == o["object"]
            held = [(int(g), int((mine & (group == g)).sum()), float(merged.size[g] * cell**2 * 1e4), bool(small[g]),
                     float(cost[g])) for g in np.unique(group[mine & (group >= 0)])]
            found.append({"episode": [e["row"], e["scene"], e["run"], e["move"]], "name": o["name"],
                          "target": o.get("target"), "points": int(mine.sum()),
                          "noise": int((mine & (group < 0)).sum()), "parts": held})
            print(found[-1], flush=True)
    small_only = [f for f in found if f["parts"] and all(s for *_, s, _ in f["parts"])]
    several = [f for f in small_only if len(f["parts"]) > 1]
    noise = sum(f["noise"] for f in found) / max(sum(f["points"] for f in found), 1)
    summed = [sum(a for _, _, a, _, _ in f["parts"]) for f in small_only]
    print(f"{len(found)} dropped objects: {len(small_only)} in parts all under min_object_area "
          f"({len(several)} split into 2-{max((len(f['parts']) for f in several), default=0)} parts; their parts' "
          f"areas summed: median {np.median(summed) if summed else 0:.1f} cm^2, {sum(a >= 10 for a in summed)} at "
          f">= 10 cm^2); DBSCAN noise {noise:.3f} of their points")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
