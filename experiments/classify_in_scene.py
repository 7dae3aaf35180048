"""PointNet where the loop uses it: segments of cluttered scenes, after 1, 3, 5, 10 fused views.

    python experiments/classify_in_scene.py --config classify_in_scene [key=value ...] [--out RESULTS.md]

For each world of the config (``synthetic``, ``touching`` gaps, ``real_like`` sensor noise with clutter;
held-out instances only) and each scene seed, the camera walks a random path over the view hemisphere
(a random start, then a random unvisited candidate within ``nbv.radius`` of the current
view, the paper's move), and every frame goes through ``perception.observe``. After the configured view
counts each segment is labelled with its majority ground-truth object (``metrics.segment_truth``: the
nearest posed object surface of its points) and its purity recorded; segments below ``purity`` are
reported apart, segments of clutter objects are not scored (the paper's protocol). Outputs in
``out_dir``: ``results.json`` (every scored segment), ``confusion.png`` and ``reliability.png``; the
Markdown tables go to stdout and ``--out``. The config and the evaluation are ``jaxcls.experiments.in_scene``.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
from pathlib import Path

import numpy as np
from scipy.special import logsumexp

from jaxcls import io, metrics, report, viz
from jaxcls.config import load_config, save_config
from jaxcls.experiments.in_scene import SMALL_SEGMENT, InSceneConfig, confusion, evaluate
from jaxcls.perception import pointnet


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="classify_in_scene", help="a path or a shipped config name")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    config = load_config(InSceneConfig, args.config, args.overrides)
    out = Path(config.out_dir)
    save_config(config, out / "config.yaml")
    summary, confusions, reliabilities, per_class, pooled, errors = [], {}, {}, [], [], []
    classifiers = {name: pointnet.load_classifier(path or None) for name, path in config.weights.items()}
    all_records = evaluate(config, classifiers)
    for name, records in all_records.items():
        classifier = classifiers[name]
        classes = classifier.classes
        for world_name in config.worlds:
            for v in config.views:
                rows = [r for r in records if r["world"] == world_name and r["views"] == v]
                pure = [r for r in rows if r["purity"] >= config.purity]
                impure = [r for r in rows if r["purity"] < config.purity]
                correct = np.array([r["predicted"] == r["true"] for r in pure], bool)
                conf = np.array([r["confidence"] for r in pure])
                cal = metrics.calibration(conf, correct)
                raw = np.array([r["logits"] for r in pure]).reshape(len(pure), -1)
                raw_conf = np.exp(raw - logsumexp(raw, axis=1, keepdims=True)).max(axis=1) if len(pure) else conf
                cal_as_trained = metrics.calibration(raw_conf, correct)
                wrong_conf = f"{conf[~correct].mean():.2f}" if (~correct).any() else ""
                impure_acc = f"{np.mean([r['predicted'] == r['true'] for r in impure]):.3f}" if impure else ""
                summary.append((name, f"{classifier.temperature:.2f}", world_name, v,
                                f"{correct.mean():.3f}" if len(pure) else "", len(pure),
                                f"{cal.ece:.3f}", f"{cal_as_trained.ece:.3f}", wrong_conf, len(impure), impure_acc))
                if v in (1, max(config.views)):
                    confusions[f"{name}, {world_name}, {v} views"] = confusion(pure, classes)
                    reliabilities[f"{name}, {world_name}, {v} views"] = cal
        for world_name in [*config.worlds, "all"]:
            pure = [r for r in records if (world_name == "all" or r["world"] == world_name)
                    and r["purity"] >= config.purity]
            raw = np.array([r["logits"] for r in pure]).reshape(len(pure), -1)
            true = np.array([r["true"] for r in pure], int)
            row = [name, f"{classifier.temperature:.2f}", world_name, len(pure)]
            for temperature in (classifier.temperature, 1.0):
                logp = raw / temperature - logsumexp(raw / temperature, axis=1, keepdims=True)
                cal = metrics.calibration(np.exp(logp).max(axis=1), logp.argmax(axis=1) == true)
                row += [f"{-logp[np.arange(len(true)), true].mean():.3f}", f"{cal.ece:.3f}"]
            pooled.append(tuple(row))
        for world_name in config.worlds:
            for v in config.views:
                wrong = [r for r in records if r["world"] == world_name and r["views"] == v
                         and r["purity"] >= config.purity and r["predicted"] != r["true"]]
                pairs = collections.Counter((classes[r["true"]], classes[r["predicted"]]) for r in wrong)
                small = sum(r["size"] < SMALL_SEGMENT for r in wrong)
                errors.append((name, world_name, v, len(wrong), small,
                               ", ".join(f"{a} -> {b} {n}" for (a, b), n in pairs.most_common(4))))
        five = [r for r in records if r["views"] == min(config.views, key=lambda v: abs(v - 5))
                and r["purity"] >= config.purity]
        for c, cls in enumerate(classes):
            mine = [r for r in five if r["true"] == c]
            per_class.append((name, cls, len(mine),
                              *(f"{np.mean([r['predicted'] == r['true'] for r in mine if r['world'] == w]):.2f}"
                                if any(r["world"] == w for r in mine) else "" for w in config.worlds)))
    io.write_json(out / "results.json", {"config": dataclasses.asdict(config), "records": all_records})
    viz.save(viz.confusion(confusions, classes), out / "confusion.png")
    viz.save(viz.reliability(reliabilities), out / "reliability.png")
    intro = (f"{config.scenes} held-out scenes per world x {config.paths} random paths; segments of target "
             f"objects with purity >= {config.purity} scored (impure ones apart); ECE over 10 bins. Figures: "
             f"`{out}/confusion.png`, `{out}/reliability.png`.")
    report.publish(report.section(
        "PointNet in the scene: accuracy and calibration of segments", argv,
        ("weights", "T", "world", "views", "accuracy", "segments", "ECE (calibrated: T)", "ECE as trained (T = 1)",
         "mean confidence when wrong", "impure segments", "their accuracy"), summary,
        intro=intro), args.out)
    report.publish(report.section(
        "PointNet in the scene: calibration, all view counts pooled", argv,
        ("weights", "T", "world", "segments", "NLL (calibrated: T)", "ECE (calibrated: T)", "NLL as trained (T = 1)",
         "ECE as trained (T = 1)"), pooled),
        args.out)
    report.publish(report.section(
        "PointNet in the scene: where the errors come from", argv,
        ("weights", "world", "views", "errors", f"of them segments under {SMALL_SEGMENT} points",
         "most frequent (true -> predicted count)"), errors), args.out)
    report.publish(report.section(
        f"PointNet in the scene: per-class accuracy after {min(config.views, key=lambda v: abs(v - 5))} views",
        argv, ("weights", "class", "segments", *config.worlds), per_class), args.out)
    print(json.dumps({"out_dir": str(out)}))


if __name__ == "__main__":
    main()
