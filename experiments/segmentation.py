"""Segmentation quality: the reference path and the JAX twin on fused scenes, against the posed objects.

Both paths (scikit-learn DBSCAN + SciPy, and ``segment_jax``) are scored against the posed object surfaces.

    python experiments/segmentation.py [--seeds 12] [--tracking reported] [--out RESULTS.md]

Scenes: the builtin set, ``synthetic`` (footprint gaps 3 mm - 3 cm) and ``touching`` (1-5 mm), seeds 0..n-1,
depth from the ``mujoco`` backend at five hemisphere views from low to high elevation, fused into the default
0.6 m / 128^3 volume through ``perception.observe``; after 1 and 5 views both paths segment the same surface.
The adjusted Rand index (ARI) is taken against each point's nearest posed object surface (points more than
1 cm from every object left out); "agreement" is the ARI between the two paths. ``--tracking`` is
``perception.tracking.mode``: ``frame_to_model`` (the default: each frame registered to the model before it is
fused) or ``reported`` (fused at the given poses, as before tracking existed). The logic is
``jaxcls.experiments.segmentation``; ``benchmarks/segment.py`` times the chain (this table was its first half).
"""

from __future__ import annotations

import argparse
import datetime

from jaxcls import perception, report
from jaxcls.experiments import segmentation
from jaxcls.geometry import Intrinsics
from jaxcls.perception.tracking import TrackingConfig


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="scenes per kind (seeds 0..n-1)")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the Kinect v1 (1 = 640x480)")
    parser.add_argument("--max-points", type=int, default=16384, help="static size of the extracted surface")
    parser.add_argument("--tracking", choices=("frame_to_model", "reported"), default="frame_to_model",
                        help="perception.tracking.mode: register each frame first, or fuse it at the given pose")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    mode = type(TrackingConfig().mode)(args.tracking)  # the block's own type for its mode (strings or their enum)
    settings = perception.PerceptionConfig(shapes=perception.ShapeConfig(surface_points=args.max_points),
                                           tracking=TrackingConfig(mode=mode))
    intr = Intrinsics.kinect_v1(args.scale)
    ari = segmentation.quality(args.seeds, args.scale, settings)
    report.publish(report.section(
        f"Segmentation quality, {intr.width}x{intr.height} depth fused into 128^3, {args.seeds} scenes per kind, "
        f"{datetime.date.today()}", argv, ("scenes", "views", "path", "mean ARI", "min ARI", "per scene"),
        segmentation.quality_rows(ari),
        intro="ARI against the posed object surfaces; `agreement` is the twin against the reference."), args.out)


if __name__ == "__main__":
    main()
