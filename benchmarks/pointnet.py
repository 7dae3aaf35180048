"""PointNet speed (training throughput, inference for 5 segments) and the recipes' held-out accuracies.

    python benchmarks/pointnet.py                                   # speed on the default JAX device
    python benchmarks/pointnet.py --runs paper=runs/paper partial=runs/pointnet_builtin --out BENCHMARKS.md

Training throughput is one jitted epoch (``train.make_train_epoch``: sampling, augmentation, forward,
backward, Adam) over the clouds of the shipped ``pointnet`` config (``jaxcls/configs/pointnet.yaml``;
generated and cached on first use; ``--batch`` with no sizes skips training).
Inference is ``pointnet.classify`` on 5 segments of 1024 points, on the CPU. ``--runs`` reads the
``metrics.json`` of finished ``jaxcls train`` runs and tabulates their held-out accuracies;
``--evaluate`` measures weights anew on the held-out clouds of ``--config`` (rendered and cached by this
tree's ``learn.clouds``), e.g. the shipped weights after a refactor:

    python benchmarks/pointnet.py --batch --repeats 1 \
        --evaluate shipped=jaxcls/perception/weights/pointnet_builtin.msgpack
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxcls import report
from jaxcls.config import load_config
from jaxcls.learn.clouds import SOURCES, load_clouds
from jaxcls.learn.train import TrainConfig, create_state, evaluation_sets, make_bank, make_train_epoch, predict_all
from jaxcls.perception import pointnet
from jaxcls.world.objects import object_set_from_config


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="pointnet", help="a path or a shipped config name")
    parser.add_argument("--batch", type=int, nargs="*", default=[32, 128])
    parser.add_argument("--steps", type=int, default=20, help="training steps timed per batch size")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--runs", nargs="*", default=[], metavar="NAME=RUN_DIR")
    parser.add_argument("--evaluate", nargs="*", default=[], metavar="NAME=WEIGHTS",
                        help="held-out accuracy of weight files (.msgpack + .json), measured now")
    parser.add_argument("--out", help="append the sections to this Markdown file")
    args = parser.parse_args(argv)
    config = load_config(TrainConfig, args.config)
    object_set = object_set_from_config(config.objects)
    M = len(object_set.classes)

    rows = []
    if args.batch:
        clouds = load_clouds(object_set, "train", config.data, config.objects, config.seed)
        mesh = Mesh(np.asarray(jax.devices()), ("data",))
        replicated = NamedSharding(mesh, PartitionSpec())
        bank = jax.device_put(make_bank(clouds, config.mix), replicated)
        for batch in args.batch:
            cfg = dataclasses.replace(config, batch_size=batch)
            epoch = make_train_epoch(cfg, M, args.steps, mesh)
            state = jax.device_put(create_state(cfg, M, args.steps), replicated)
            _, med, _ = report.timed(lambda e=epoch, s=state: e(s, bank, jax.random.key(0)), args.repeats)
            rows.append((f"training, batch {batch} x {config.model.num_points} points", report.device_name(),
                         f"{med / args.steps * 1e3:.2f} ms/step", f"{batch * args.steps / med:.0f} clouds/s"))
            print(rows[-1])
    with jax.default_device(jax.devices("cpu")[0]):
        variables = pointnet.init_variables(jax.random.key(0), M, config.model)
        classifier = pointnet.Classifier(variables, object_set.classes, config.model)
        points = jax.random.normal(jax.random.key(1), (5, 1024, 3)) * 0.05
        mask = jnp.ones((5, 1024), bool)
        _, med, _ = report.timed(lambda: pointnet.classify(classifier, points, mask), args.repeats * 4)
        rows.append(("inference (`classify`), 5 segments x 1024 points",
                     report.cpu_name(),
                     f"{med * 1e3:.1f} ms", f"{5 / med:.0f} segments/s"))
        print(rows[-1])
    report.publish(report.section(f"PointNet speed, {datetime.date.today()}", argv,
                                  ("operation", "device", "median", "throughput"), rows), args.out)

    if args.runs:
        table, finals = [], {}
        for item in args.runs:
            name, _, run = item.partition("=")
            metrics = json.loads((Path(run) / "metrics.json").read_text())
            final = finals[name] = metrics["final"]
            last = metrics["history"][-1]
            table.append((name, *(f"{final[s]['accuracy']:.3f}" if s in final else "" for s in SOURCES),
                          len(metrics["history"]), f"{last['clouds_per_second']:.0f}"))
        report.publish(report.section(
            f"PointNet recipes, held-out instances, {datetime.date.today()}", argv,
            ("recipe", *(f"accuracy, {s}" for s in SOURCES), "epochs", "training clouds/s"), table,
            intro="Accuracy on the held-out instances of the builtin set: complete clouds at 8 yaws, single "
                  "views without occluders (`view`), views with occluders, 2-3 views fused. Per-class "
                  "figures and confusion matrices are in each run's metrics.json."), args.out)
        columns = [(name, s) for name in finals for s in ("full", "view") if s in finals[name]]
        per_class = [(c, *(f"{finals[n][s]['per_class'][c]:.2f}" for n, s in columns)) for c in object_set.classes]
        report.publish(report.section(
            f"PointNet per-class accuracy, held-out instances, {datetime.date.today()}", argv,
            ("class", *(f"{n}, {s}" for n, s in columns)), per_class), args.out)

    if args.evaluate:
        test = load_clouds(object_set, "test", config.data, config.objects, config.seed,
                           perception=config.perception)
        sets = evaluation_sets(test, config)
        table = []
        for item in args.evaluate:
            name, _, path = item.partition("=")
            weights = pointnet.load_classifier(path, classes=object_set.classes)

            def accuracy(source: str, weights=weights) -> str:
                points, mask, label = sets[source]
                return f"{np.mean(predict_all(weights, points, mask, config.eval_batch) == label):.3f}"

            table.append((name, *(accuracy(s) if s in sets else "" for s in SOURCES),
                          " ".join(f"{s}: {len(sets[s][2])}" for s in SOURCES if s in sets)))
            print(table[-1])
        report.publish(report.section(
            f"PointNet weights evaluated on the held-out instances, {datetime.date.today()}", argv,
            ("weights", *(f"accuracy, {s}" for s in SOURCES), "clouds"), table,
            intro=f"Held-out clouds of `{args.config}` (complete clouds at {config.eval_rotations} yaws), made "
                  "and classified by this tree."), args.out)


if __name__ == "__main__":
    main()
