"""Table 1 episodes of several settings on the same scenes, paired: camera tracking and the class decision.

    python experiments/tracking_runs.py --dataset real_like --classes 8 \\
        --run new=results/tracking/real_like_new.jsonl.xz --run old=results/tracking/real_like_old.jsonl.xz \\
        [--baseline old] [--out RESULTS.md]

Each ``--run name=path`` is an ``episodes.jsonl`` (or its ``.xz`` archive) written by ``experiments/table1.py``
with one setting (e.g. ``perception.tracking.mode=reported decision=last`` against the defaults), on the same
dataset, seed, starts and keys, so every (row, scene, run) episode has a partner in each file. For every row
the table gives F1 after T/2 and T moves with 95% scene-bootstrap intervals and the paired F1@T - F1@T/2 (does
the last half of the episode help?), then each setting against ``--baseline`` on the same episodes (paired by scene).

With ``--dataset`` (a shipped dataset config name or path: its ``seed`` and sensor give each scene's true
hand-eye error, ``T_reported = T_true @ dT``, drawn as ``jaxcls dataset`` draws it, without rendering), the
hand-eye estimate of the records (``hand_eye``: the estimate Y after each move, true Y = dT^-1) is compared
with the truth after moves 1, 3 and T: translation (mm) and rotation (deg), median and 95th percentile.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from jaxcls import io, metrics, report
from jaxcls.config import load_config
from jaxcls.episode import protocol
from jaxcls.experiments.table1.scoring import row_scores
from jaxcls.perception import tracking
from jaxcls.world.dataset import DatasetConfig, scene_key
from jaxcls.world.render.sensor import perturb_poses


def true_hand_eye(dataset: str, scenes: int) -> np.ndarray:
    """[S, 4, 4] each scene's true camera-side correction Y = dT^-1 (``T_true = T_reported @ Y``)."""
    config = load_config(DatasetConfig, dataset)
    if not (config.sensor.pose_noise and config.sensor.pose_noise_shared):
        raise ValueError(f"{dataset}: needs sensor.pose_noise and pose_noise_shared (one hand-eye error per scene)")
    out = []
    for s in range(scenes):
        _, key_pose = jax.random.split(scene_key(config.seed, s))
        dT = np.asarray(perturb_poses(key_pose, jnp.eye(4, dtype=jnp.float64), config.sensor), np.float64)
        out.append(np.linalg.inv(dT))
    return np.stack(out)


def hand_eye_table(records: list[dict], truth: np.ndarray, moves: list[int]) -> str:
    """Error of the records' hand-eye estimates against ``truth`` [S, 4, 4] after each of ``moves``."""
    rows = [("reported poses (no estimate)",
             *[_summary([tracking.pose_error(np.eye(4), truth[int(r["scene"])]) for r in records])] * len(moves))]
    cells = []
    for t in moves:
        errors = []
        for r in records:
            if len(r.get("hand_eye", [])) >= t:
                Y = np.asarray(jaxlie.SE3.exp(jnp.asarray(r["hand_eye"][t - 1], jnp.float64)).as_matrix(), np.float64)
                errors.append(tracking.pose_error(Y, truth[int(r["scene"])]))
        cells.append(_summary(errors))
    rows.append(("online estimate", *cells))
    return report.table(("hand-eye Y", *(f"after move {t}" for t in moves)), rows)


def _summary(errors: list[tuple[float, float]]) -> str:
    e = np.asarray(errors, np.float64).reshape(-1, 2)
    if not len(e):
        return "-"
    return (f"{np.median(e[:, 0]):.2f} / {np.percentile(e[:, 0], 95):.2f} mm, "
            f"{np.median(e[:, 1]):.3f} / {np.percentile(e[:, 1], 95):.3f} deg")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, help="name=episodes.jsonl (repeat)")
    parser.add_argument("--baseline", help="the run the others are paired against (default: the last)")
    parser.add_argument("--classes", type=int, default=8, help="number of classes (the builtin set: 8)")
    parser.add_argument("--dataset", help="dataset config for the true hand-eye errors (e.g. real_like)")
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--resamples", type=int, default=2000)
    parser.add_argument("--out", help="append the tables to this Markdown file")
    args = parser.parse_args(argv)
    runs = dict(r.split("=", 1) for r in args.run)
    records = {name: list(io.read_jsonl(path)) for name, path in runs.items()}
    baseline = args.baseline or list(runs)[-1]
    T, half = args.moves, max(1, args.moves // 2)
    rows = sorted({r["row"] for recs in records.values() for r in recs})
    lines = []
    for row in rows:
        for name, recs in records.items():
            mine = {(r["scene"], r["run"]): r for r in recs if r["row"] == row}
            base = {(r["scene"], r["run"]): r for r in records[baseline] if r["row"] == row}
            keys = sorted(set(mine) & set(base))
            if not keys:
                continue
            a = [mine[k] for k in keys]
            end, mid = row_scores(a, args.classes, T, args.resamples), row_scores(a, args.classes, half, args.resamples)
            gain = metrics.paired_difference(protocol.per_scene(a, T), protocol.per_scene(a, half), args.classes,
                                             resamples=args.resamples)
            if name == baseline:
                versus = "-"
            else:
                d = metrics.paired_difference(protocol.per_scene(a, T), protocol.per_scene([base[k] for k in keys], T),
                                              args.classes, resamples=args.resamples)
                versus = metrics.format_difference(*d)
            refused = np.mean([s == "refused" for r in a for s in r.get("tracking", [])] or [0.0])
            lines.append((row, name, f"{mid['f1']:.3f} [{mid['f1_low']:.3f}, {mid['f1_high']:.3f}]",
                          f"{end['f1']:.3f} [{end['f1_low']:.3f}, {end['f1_high']:.3f}]",
                          metrics.format_difference(*gain), versus, f"{refused:.3f}", len(a)))
    markdown = (f"`{report.command_line(argv)}`\n\n"
                + report.table(("row", "setting", f"F1 after {half}", f"F1 after {T}", f"F1@{T} - F1@{half} (paired)",
                                f"F1@{T} - {baseline} (paired)", "frames refused", "episodes"), lines) + "\n")
    if args.dataset:
        every = [r for recs in records.values() for r in recs if r.get("hand_eye")
                 and any(s != "reported" for s in r.get("tracking", []))]
        truth = true_hand_eye(args.dataset, 1 + max(int(r["scene"]) for r in every))
        markdown += ("\nThe online hand-eye estimate against the true one (median / 95th percentile over episodes, "
                     "every tracked run and row):\n\n" + hand_eye_table(every, truth, [1, 3, T]) + "\n")
    report.publish(markdown, args.out)


if __name__ == "__main__":
    main()
