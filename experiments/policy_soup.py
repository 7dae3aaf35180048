"""A uniform weight soup of view policies: the mean, leaf by leaf, of several weights files of one width, feature
layout and candidate count, written as one weights file (a drop-in ``nbv.learned.weights``).

    python experiments/policy_soup.py --out runs/soup/policy.msgpack \\
        results/learned_policy_2026-11-29/ppo/training_paper_ppo550/policy.msgpack \\
        results/learned_policy_2026-11-29/ppo/training_paper_ppo300_scenes256_250/policy.msgpack [...]

Averaging weights is meaningful only for networks fine-tuned from one ancestor (they share a basin): the PPO
continuations of one policy, say. The soup's ``.json`` names its members and their sha256; nothing is selected.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import jax
import numpy as np

from jaxcls.planning import learned


def soup(members: list[dict]) -> dict:
    """The leaf-wise mean of ``members`` (weights of one tree structure and shapes); ValueError naming the first
    member that differs from the first."""
    if not members:
        raise ValueError("policy soup: no weights to average")
    first = jax.tree.structure(members[0])
    shapes = [np.shape(a) for a in jax.tree.leaves(members[0])]
    for i, m in enumerate(members[1:], start=1):
        if jax.tree.structure(m) != first or [np.shape(a) for a in jax.tree.leaves(m)] != shapes:
            raise ValueError(f"policy soup: member {i} has other layers or shapes than member 0 (another width or "
                             "feature layout)")
    return jax.tree.map(lambda *leaves: np.mean(np.stack([np.asarray(x, np.float64) for x in leaves]), axis=0)
                        .astype(np.float32), *members)


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("members", nargs="+", help="weights files (.msgpack with their .json) or shipped names")
    parser.add_argument("--out", required=True, help="the soup's .msgpack (its .json is written beside it)")
    args = parser.parse_args(argv)
    paths = [learned.weights_file(p) for p in args.members]
    first = paths[0].with_suffix(".json")
    if not first.is_file():
        raise FileNotFoundError(f"policy soup: {first} not found (weights come as a .msgpack and a .json)")
    candidates = json.loads(first.read_text()).get("max_candidates")
    if not isinstance(candidates, int):
        raise ValueError(f"{first}: no 'max_candidates' (not a view policy's weights?)")
    loaded = [learned.load(p, candidates) for p in paths]  # (each file checked: kind, shapes, candidate count)
    layouts = {info.features for _, info in loaded}
    if len(layouts) > 1:
        raise ValueError(f"policy soup: the members read feature layouts {sorted(int(x) for x in layouts)}")
    weights = soup([w for w, _ in loaded])
    agreed = {k: loaded[0][1].metadata[k] for k in ("table1", "classifier", "base", "labels")
              if k in loaded[0][1].metadata and all(i.metadata.get(k) == loaded[0][1].metadata[k] for _, i in loaded)}
    metadata = {"trained_by": "experiments/policy_soup.py (a uniform soup)", **agreed,  # (what every member says)
                "soup": [{"file": str(p), "sha256": hashlib.sha256(p.read_bytes()).hexdigest()} for p in paths]}
    out = learned.save(args.out, weights, candidates, metadata)
    print(f"policy soup of {len(paths)} members -> {out}")
    return out


if __name__ == "__main__":
    main()
