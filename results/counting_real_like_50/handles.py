"""Where N estimated loses labels that N given gets right (issue 35, RESULTS.md "Counting ... real-like set").

    python results/counting_real_like_50/handles.py KNOWN_DIR ESTIMATED_DIR OUT.json   (replays, then the summary)
    python results/counting_real_like_50/handles.py OUT.json                           (the summary of a replay)

For each episode of the estimated run whose scene holds a jug or mug target (the classes with a handle), its
recorded views are fused again through the run's perception; after moves 3 and 10 the reference path segments
the surface twice, with the run's settings (N estimated) and with N known (5 segments), and the object's surface
points (their nearest posed object within 1 cm) that N estimated drops (label -1) while N known keeps them are
counted, with the share of them at the handle's end (object-frame x within 2 cm of the object's largest x: the
builtin handles stand on +x). Each such (episode, move, object) is crossed with its refined label after that
move in both runs: ``flip`` right with N given, wrong with N estimated; ``back`` the reverse; ``same`` otherwise.
The parts (``segment.reference._watershed_reference`` after the merge, N estimated) that hold the points lost are
described: footprint area (cm^2) and the cost of their cheapest merge (< 1: touching another part, the relative
persistence; >= 1: apart on the table).
"""

from __future__ import annotations

import collections
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np


def replay(known_dir: Path, estimated_dir: Path) -> list[dict]:
    import jax
    import jax.numpy as jnp

    from jaxcls import metrics, perception
    from jaxcls.config import load_config
    from jaxcls.experiments.table1 import data
    from jaxcls.experiments.table1.config import Table1Config
    from jaxcls.perception import observation, segment
    from jaxcls.perception.foreground import foreground_mask
    from jaxcls.perception.segment import common, reference
    from jaxcls.perception.settings import ObjectCount
    from jaxcls.world.scenes import scene_models

    config = load_config(Table1Config, estimated_dir / "config.yaml")
    kconfig = load_config(Table1Config, known_dir / "config.yaml")
    E = {(r["row"], r["scene"], r["run"]): r for r in data.stored_records(config, estimated_dir / "episodes.jsonl")}
    K = {(r["row"], r["scene"], r["run"]): r for r in data.stored_records(kconfig, known_dir / "episodes.jsonl")}
    _, scene_set = data.open_scenes(config)
    reconstruct = jax.jit(observation.reconstruct)
    known = dataclasses.replace(config.perception, shapes=dataclasses.replace(
        config.perception.shapes, num_objects=ObjectCount.known, num_segments=kconfig.perception.shapes.num_segments))
    rows, cache = [], {}
    for key in sorted(E, key=lambda k: (k[1], k[0], k[2])):
        i = key[1]
        if i not in cache:
            cache.clear()
            f = scene_set.load([i])[0]
            cache[i] = f, metrics.PointOwners(f.scene, scene_models(f.scene))
        frames, owners = cache[i]
        objs = frames.scene.objects
        handled = [j for j, o in enumerate(objs) if o.target and o.class_name in ("jug", "mug")]
        if not handled:
            continue
        targets = [j for j, o in enumerate(objs) if o.target]
        spec = perception.Spec.create(config.perception, frames.intrinsics, frames.table_height)
        kspec = perception.Spec.create(known, frames.intrinsics, frames.table_height)
        state = perception.init_state(spec)
        e, k = E[key], K[key]
        for t, view in enumerate(e["path"], start=1):
            depth, T = frames.frame(view)
            state = reconstruct(spec, state, jnp.asarray(depth, jnp.float32), jnp.asarray(T, jnp.float32))
            if t not in (3, 10):
                continue
            s = state.surface
            p, n, m = np.asarray(s.points), np.asarray(s.normals), np.asarray(s.mask)
            own = owners(p, m)
            lab = np.asarray(segment.segment(spec, p, n, m).labels)
            klab = np.asarray(segment.segment(kspec, p, n, m).labels)
            fg = np.flatnonzero(np.asarray(foreground_mask(spec, jnp.asarray(p), jnp.asarray(m))))
            parts = reference._watershed_reference(spec, p[fg].astype(np.float64), n[fg].astype(np.float64))
            group = np.full(len(p), -1)
            if parts is not None:
                group[fg[parts.good]] = parts.group
                cost, _ = common._merge_costs(np, parts.merged, parts.peak, common._count_rule(spec))
            for j in handled:
                o = objs[j]
                mine = (own == j) & m
                c, sn = np.cos(o.yaw), np.sin(o.yaw)
                d = p[:, :2] - np.array(o.position)
                lx = c * d[:, 0] + sn * d[:, 1]
                end = lx[mine].max() if mine.any() else 0.0
                lost = mine & (lab < 0) & (klab >= 0)
                ti = targets.index(j)
                held = [(float(parts.merged.size[g] * spec.segmentation.footprint_cell ** 2 * 1e4), float(cost[g]))
                        for g in np.unique(group[lost & (group >= 0)])]
                rows.append({"row": key[0], "scene": key[1], "run": key[2], "move": t, "class": o.class_name,
                             "points": int(mine.sum()), "lost": int(lost.sum()),
                             "lost_handle_end": int((lost & (lx > end - 0.02)).sum()), "true": e["true"][ti],
                             "known": k["refined"][t - 1][ti], "estimated": e["refined"][t - 1][ti],
                             "parts": held})
        print(key, file=sys.stderr, flush=True)
    return rows


def summary(rows: list[dict], lost_min: int = 10) -> str:
    lines = ["| after move | class | episodes | handle lost (>= 10 points dropped that N given keeps) | median "
             "points lost | share of them at the handle's end | their parts: median area (cm^2), touching, median "
             "persistence where touching | flips where lost | flips where kept | back |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for move in (3, 10):
        for cls in ("jug", "mug"):
            R = [r for r in rows if r["move"] == move and r["class"] == cls]
            lost = [r for r in R if r["lost"] >= lost_min]
            c = collections.Counter()
            for r in R:
                flip = r["known"] == r["true"] and r["estimated"] != r["true"]
                back = r["known"] != r["true"] and r["estimated"] == r["true"]
                c[(r["lost"] >= lost_min, "flip" if flip else "back" if back else "same")] += 1
            share = sum(r["lost_handle_end"] for r in lost) / max(sum(r["lost"] for r in lost), 1)
            med = int(np.median([r["lost"] for r in lost])) if lost else 0
            held = [h for r in lost for h in r.get("parts", [])]
            touch = [c for _, c in held if c < 1]
            where = (f"{np.median([a for a, _ in held]):.1f}, {len(touch)} of {len(held)}, "
                     f"{np.median(touch) if touch else float('nan'):.2f}" if held else "")
            lines.append(f"| {move} | {cls} | {len(R)} | {len(lost)} | {med} | {share:.2f} | {where} "
                         f"| {c[(True, 'flip')]} | {c[(False, 'flip')]} | {c[(True, 'back')] + c[(False, 'back')]} |")
    return "\n".join(lines)


if __name__ == "__main__":
    if len(sys.argv) == 4:
        found = replay(Path(sys.argv[1]), Path(sys.argv[2]))
        Path(sys.argv[3]).write_text(json.dumps(found))
    print(summary(json.loads(Path(sys.argv[-1]).read_text())))
