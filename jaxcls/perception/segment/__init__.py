"""Segmentation of the fused surface into N object candidates, or as many as it counts, at most N (paper
Sec. 3.1; the foreground step before it is ``perception.foreground``).

The paper isolates the foreground by truncating depth and removing the table plane, fuses it, cuts the
reconstruction to a cube of interest, clusters it with DBSCAN and forces N clusters with K-means on the
cluster centres. DBSCAN merges objects that touch, so regrouping clusters cannot recover them; the step
after DBSCAN here splits them with a watershed on the table plane. Objects stand upright with disjoint
footprints, so the points' footprint (their xy occupancy, closed, holes filled) is a union of convex-ish
blobs joined by narrow necks where objects touch. The watershed runs on a field that peaks at object
centres: the footprint's distance to empty space times Hough votes for the vertical axis each side-wall
point faces (a point with outward normal n votes for p - r n_xy over a range of radii r). Its basins are
merged by persistence (peak minus saddle, lowest first) until N remain; a basin with no saddle to a higher
one (a separate DBSCAN cluster) has the empty space around it as its saddle (field 0) and joins the nearest
centre: the paper's merge of cluster centres, which takes small fragments early and separate objects last.
With fewer than N basins the part with the largest sum of squares is split by 2-means (K-means).

Without a known N (``shapes.num_objects: estimated``; ``num_segments`` is then the number of slots, the most
objects that can be found), the merge orders basins by their persistence relative to their own peak,
(peak - saddle) / peak, and stops once the cheapest is at least ``merge_persistence`` and no more basins live
than slots; basins apart on the table (no saddle) merge only to fit the slots. Two touching basins that are
flush (their highest points within ``flush_height`` of each other, and at least half of the adjacent cell pairs
across their boundary too: one object's top surface running on, as a box's whose footprint ridge holds two
peaks) merge up to the higher ``flush_persistence`` (their cost scaled by merge_persistence / flush_persistence).
Then a part whose footprint covers less than ``absorb_area`` and that touches a larger part of at least
``min_object_area`` joins the one it shares the highest saddle with, whatever its persistence: a jug's or mug's
handle is a small basin of its own, which dropped left a bottle or a cup. Nothing is split; parts whose footprint
covers less than ``min_object_area`` that touch no larger part are dropped as fragments. Slots beyond the count
are empty (their masks all False), ordered last.

Two implementations of the same algorithm:
- ``segment``: the reference path, scikit-learn DBSCAN + SciPy grid operations on the host (one episode).
- ``segment_jax``: the scale path's twin, jittable with static shapes and vmappable over episodes: DBSCAN's
  noise rule on a grid, hole filling by connected components (label propagation with hooking), an exact
  separable distance transform, at most ``max_basins`` basins, fixed-length merge and K-means loops.

Conventions (docs/ARCHITECTURE.md): metres, world z up, table top at z = ``spec.table_height``; OpenCV camera, ``T_wc``
camera-to-world; depth z-depth with 0 = no return. Point sets are padded: ``points [P, 3]`` + ``mask [P]``;
segments ``[N, Ps, 3]`` + ``[N, Ps]``. Labels ``[P]`` i32 give each point's segment, -1 = not
foreground or noise.

Files: ``common`` (shared by both paths), ``reference`` (scikit-learn), ``grid`` (JAX grid operations),
``twin`` (the JAX path). Names with a leading underscore are this subpackage's internal API, shared
between its modules, not the package's. Settings: ``perception.settings.SegmentConfig`` (the algorithm)
and ``ShapeConfig`` (N, Ps), read through the ``Spec``.
"""

from jaxcls.perception.segment.common import Segments, pack_segments
from jaxcls.perception.segment.reference import cluster_reference, footprint_field_reference, segment
from jaxcls.perception.segment.twin import cluster_jax, segment_jax
from jaxcls.perception.settings import SegmentConfig

__all__ = ["SegmentConfig", "Segments", "cluster_jax", "cluster_reference", "footprint_field_reference",
           "pack_segments", "segment", "segment_jax"]
