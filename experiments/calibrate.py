"""Fit the classifier's temperature on segments of held-out *training-instance* scenes (never the test
scenes) and write weights that carry it (temperature scaling: probabilities softmax(logits / T)).

    python experiments/calibrate.py [--scenes 10] [--write jaxcls/perception/weights/pointnet_builtin.msgpack]

Scenes: the worlds of ``jaxcls/configs/classify_in_scene.yaml`` with ``scene.split=train`` and another
seed, so neither the instances nor the scenes are the evaluation's. Every scored segment (target,
purity >= the config's) after every view count enters the fit. ``--write`` saves the weights with the
fitted temperature there (the .json beside gains ``temperature``); then
``python experiments/classify_in_scene.py`` measures the calibrated scores on the test scenes.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
from pathlib import Path

import numpy as np
from scipy.special import log_softmax

from jaxcls import metrics, report
from jaxcls.config import load_config
from jaxcls.experiments.in_scene import InSceneConfig, evaluate
from jaxcls.perception import pointnet


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default="", help="weights to calibrate (default: the shipped ones)")
    parser.add_argument("--scenes", type=int, default=10, help="training-instance scenes per world")
    parser.add_argument("--seed", type=int, default=1000, help="scene seeds (the evaluation uses 0)")
    parser.add_argument("--write", help="save the calibrated weights here (.msgpack + .json)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    config = load_config(InSceneConfig, "classify_in_scene", [f"scenes={args.scenes}", f"seed={args.seed}"])
    worlds = {name: dataclasses.replace(w, scene=dataclasses.replace(w.scene, split="train"))
              for name, w in config.worlds.items()}
    config = dataclasses.replace(config, worlds=worlds)
    classifier = pointnet.load_classifier(args.weights or None)
    records = [r for r in evaluate(config, {"fit": dataclasses.replace(classifier, temperature=1.0)})["fit"]
               if r["purity"] >= config.purity]
    scores = np.array([r["logits"] for r in records])
    labels = np.array([r["true"] for r in records])
    temperature = pointnet.fit_temperature(scores, labels)
    rows = []
    for name, t in (("as trained (T = 1)", 1.0), (f"fitted (T = {temperature:.3f})", temperature)):
        logp = log_softmax(scores / t, axis=1)
        probs = np.exp(logp)
        cal = metrics.calibration(probs.max(axis=1), probs.argmax(axis=1) == labels)
        rows.append((name, f"{-logp[np.arange(len(labels)), labels].mean():.3f}", f"{cal.ece:.3f}",
                     f"{np.mean(probs.argmax(axis=1) == labels):.3f}", len(labels)))
    report.publish(report.section(
        f"Temperature scaling fitted on training-instance scenes, {datetime.date.today()}", argv,
        ("scores", "NLL", "ECE", "accuracy", "segments"), rows,
        intro=f"{args.scenes} scenes per world ({', '.join(worlds)}) of training instances, seeds from "
              f"{args.seed}, views {list(config.views)}, purity >= {config.purity}."), args.out)
    if args.write:
        calibrated = dataclasses.replace(classifier, temperature=temperature)
        info = json.loads(Path(args.weights or pointnet.BUILTIN_WEIGHTS).with_suffix(".json").read_text())
        metadata = {k: v for k, v in info.items() if k not in ("classes", "model", "temperature")}
        metadata["calibration"] = {"fitted_on": f"{args.scenes} training-instance scenes per world, seeds from "
                                                f"{args.seed}", "segments": len(labels)}
        print(f"wrote {pointnet.save_classifier(args.write, calibrated, metadata)}")


if __name__ == "__main__":
    main()
