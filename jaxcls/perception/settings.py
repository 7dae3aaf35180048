"""A move's perception settings, one block per concern, and the static ``Spec`` the stages read.

YAML (the ``perception:`` block of a command's config)::

    perception:
      foreground: {table_eps: 0.01, max_depth: 1.5}        # which pixels are objects
      volume: {center: [0, 0, 0.25], size: 0.6, resolution: 128, truncation_voxels: 4,  # the TSDF cube
               storage: float32, slabs: 1,         # or compact (tsdf.VolumeStorage): 6.3 MB, not 16.8 MB
               kernel: xla}                        # or pallas, interpreted (tsdf.FusionKernel): one GPU kernel
      segmentation: {dbscan_eps: 0.01, ...}                # DBSCAN, footprint votes, K-means, twin bounds
      shapes: {num_segments: 5, points_per_segment: 1024, surface_points: 16384,       # static shapes
               segments_per_pass: 0}                     # PointNet's segments a pass (0: all)
      segmenter: jax                                       # or reference (scikit-learn, host)
      tracking: {mode: frame_to_model, ...}                # each frame registered to the model before fusion
      classification_precision: float32                    # or tf32, bfloat16: PointNet on a GPU's tensor cores
      classification_pooling: xla                          # or pallas, interpreted: the pooling as a GPU kernel

The table height is not here: it belongs to the world (``SceneConfig.table_height``, a dataset's scene, a
recording's ``meta.json``) and reaches perception through ``Spec.create(..., table_height=...)``. The
volume's centre is given relative to the table top's centre, so it follows the table too.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import TYPE_CHECKING

import numpy as np
from flax import struct

from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import Intrinsics
from jaxcls.perception.pointnet import PoolingKernel
from jaxcls.perception.tracking import TrackingConfig
from jaxcls.perception.tsdf import FusionKernel, VolumeStorage
from jaxcls.precision import MatmulPrecision

if TYPE_CHECKING:
    from jaxcls.perception.pointnet import Classifier



class Segmenter(enum.StrEnum):
    """Which implementation segments the surface (``perception.segment``): ``jax``, the JAX twin (the
    default: one program with the rest of the move, vmappable, on any device); ``reference``, scikit-learn
    DBSCAN and K-means on the host, reached from the move's program through ``jax.pure_callback``."""

    jax = "jax"
    reference = "reference"


class ObjectCount(enum.StrEnum):
    """How many objects the segmentation looks for (``perception.shapes.num_objects``): ``known``, exactly
    ``shapes.num_segments`` (the paper: basins merged down to N, the largest part split by 2-means up to N);
    ``estimated``, as many as the data shows, at most ``shapes.num_segments`` (basins merged only while their
    relative persistence is below ``segmentation.merge_persistence`` or there are more than the slots; no
    splits; parts under ``segmentation.absorb_area`` joined to a larger touching part, those under
    ``segmentation.min_object_area`` touching none dropped); slots beyond the count have empty masks."""

    known = "known"
    estimated = "estimated"


@dataclasses.dataclass(frozen=True)
class ForegroundConfig:
    """Which depth pixels and surface points are objects: above the table band, nearer than ``max_depth``."""

    table_eps: float = bounded(0.01, ge=0.0)  # points with z <= table height + table_eps are table (>= 1 voxel)
    max_depth: float = bounded(1.5, gt=0.0)  # depth beyond this is background, m (views are 1 m away)

    def __post_init__(self) -> None:
        check_bounds(self, "foreground.")


@dataclasses.dataclass(frozen=True)
class VolumeConfig:
    """The TSDF cube: the paper's space of interest around the objects. Lengths in metres."""

    center: tuple[float, float, float] = (0.0, 0.0, 0.25)  # relative to the table top's centre
    size: float = bounded(0.6, gt=0.0)  # edge of the cube
    resolution: int = bounded(128, ge=2)  # voxels per edge (0.6 m / 128 = 4.7 mm)
    truncation_voxels: float = bounded(4.0, gt=0.0)  # half-width of the TSDF band, in voxels
    storage: VolumeStorage = VolumeStorage.float32  # or compact: i16 values, u8 weights (3 of 8 bytes a voxel)
    # The fusion updates the volume in this many slabs along x, one after another: its float32 temporaries span
    # a slab (what bounds a GPU's batch of episodes; the pallas kernel on a GPU has none and ignores them);
    # 1 = one pass over the volume (the fastest on a CPU).
    slabs: int = bounded(1, ge=1)
    # How the fusion runs (tsdf.FusionKernel): xla (vectorised JAX, the reference; differentiable), pallas (on a GPU
    # one Triton kernel over blocks of voxels, updated in place, no temporaries; elsewhere xla) or interpreted (the
    # kernel interpreted anywhere: slow, to check it off a GPU).
    kernel: FusionKernel = FusionKernel.xla

    def __post_init__(self) -> None:
        check_bounds(self, "volume.")
        if self.resolution % self.slabs:
            raise ValueError(f"volume.slabs ({self.slabs}) must divide volume.resolution ({self.resolution})")

    @property
    def voxel_size(self) -> float:
        return self.size / self.resolution


@dataclasses.dataclass(frozen=True)
class SegmentConfig:
    """The segmentation algorithm's settings (both paths; the last two bound the JAX twin only)."""

    # DBSCAN (3D) drops noise; surface points are ~ one 4.7 mm voxel apart, 2 voxels bridge a missed one.
    dbscan_eps: float = bounded(0.01, gt=0.0)
    dbscan_min_samples: int = bounded(5, ge=1)
    # Footprint grid on the table plane (objects stand upright with disjoint footprints).
    footprint_cell: float = bounded(0.005, gt=0.0)
    closing_steps: int = bounded(1, ge=0)  # fills gaps between surface points ~ one voxel apart
    # Centre votes: side-wall points (|n_xy| > vote_min_horizontal) vote along -n_xy at vote_radii radii
    # up to vote_max_radius (the largest object radius); votes are blurred by vote_sigma cells.
    vote_min_horizontal: float = bounded(0.5, ge=0.0, lt=1.0)
    vote_max_radius: float = bounded(0.10, gt=0.0)
    vote_radii: int = bounded(20, ge=1)
    vote_sigma: float = bounded(1.0, gt=0.0)
    vote_exponent: float = bounded(0.5, ge=0.0)  # field = distance to empty * (votes / max) ** exponent
    # K-means splits (fewer basins than N): points enter as (x, y, w z), so tall objects are not cut at
    # mid-height; at most kmeans_iters Lloyd rounds.
    kmeans_iters: int = bounded(20, ge=1)
    kmeans_z_weight: float = bounded(0.25, ge=0.0)
    # Estimated object count only (shapes.num_objects = estimated): basins are merged, lowest first, while
    # (peak - saddle) / peak, the persistence of the lower one relative to its own peak, is below
    # merge_persistence (parts apart on the table never, unless there are more than the slots), and parts whose
    # footprint (closed, filled cells) covers less than min_object_area m^2 are dropped as fragments. Chosen on
    # rendered scenes (seeds 100-129) disjoint from RESULTS.md's "Counting objects" (0-29): 0.15 counted best
    # after 3 views of 0.1-0.4 (one object's basins merge at 0.02-0.28, touching objects' at 0.1-0.9: they
    # overlap; with the flush and absorb rules below, 0.10-0.20 within two walks of 90 on the tuning walks).
    # min_object_area 5 cm^2 (10 before the absorb rule): with small touching parts absorbed it only drops
    # isolated fragments, and most objects missed after 3 moves were barely seen ones whose part apart from the
    # rest was small; 5 of 3 / 5 / 7 / 10 cm^2 counted best after 3 moves on both sets' tuning walks
    # (results/counting_min_area_tune; RESULTS.md, "Counting objects without a known N").
    merge_persistence: float = bounded(0.15, ge=0.0, le=1.0)
    min_object_area: float = bounded(0.0005, ge=0.0)
    # Estimated count only: two touching basins that are flush, their highest points within flush_height m of
    # each other and at least half of the cell pairs across their boundary too (one object's top surface running
    # on, as a box's, a bowl's rim), merge while their relative persistence is below flush_persistence
    # (>= merge_persistence; equal: the rule is off). Most extra segments in Table 1's episodes were such second
    # basins of one box, bowl or drill (persistence 0.15-0.9); chosen on a tuning set of scenes (dataset seed
    # 100) disjoint from RESULTS.md's (RESULTS.md, "Counting objects without a known N").
    flush_persistence: float = bounded(0.5, ge=0.0, le=1.0)
    flush_height: float = bounded(0.003, ge=0.0)
    # Estimated count only: after the persistence merge, a part whose footprint covers less than absorb_area m^2
    # and that touches (shares a saddle with) a larger part of at least min_object_area joins the one it shares
    # the highest saddle with, whatever its persistence (0: off); parts under min_object_area apart from every
    # larger part are dropped. A jug's or mug's handle is such a part (~3-5 cm^2, relative persistence ~0.3):
    # dropped, it left a bottle or a cup; above min_object_area, a bowl's second wall. 15 cm^2 counted best of
    # 10 / 15 / 20 on the tuning walks (dataset seed 100, both sets; RESULTS.md, "Counting objects without a
    # known N"; min_object_area was 10 then: absorb_area = min_object_area leaves the persistence merge's count).
    absorb_area: float = bounded(0.0015, ge=0.0)
    # Estimated count only, with GR: after GR a live segment whose points lie on a larger live segment's aligned
    # model, explained_share of them or more within explained_distance m of its surface, is no object of its own
    # (``refine.explained``: a second arc of one bowl's wall, a box's second face); 0: off. Chosen on Table 1's
    # episodes of the synthetic tuning scenes (dataset seed 100, 30 scenes x 3 runs, VisOcclHistGR and InfoGainGR):
    # N right after 3 moves 0.933 / 0.956 off, 0.978 / 0.989 at 0.8 or 0.6 within 1 cm, 0.967 / 0.989 at 0.8
    # within 5 mm; 0.8 the stricter of the two tied (RESULTS.md, "Counting objects without a known N").
    explained_share: float = bounded(0.8, ge=0.0, le=1.0)
    explained_distance: float = bounded(0.01, gt=0.0)
    # JAX twin only: static bounds.
    max_basins: int = bounded(64, ge=1)  # basins kept (highest peaks); the others join the nearest kept one
    max_cc_iters: int = bounded(64, ge=1)  # label-propagation rounds (about log of the diameter suffice)

    def __post_init__(self) -> None:
        check_bounds(self, "segmentation.")
        if self.flush_persistence < self.merge_persistence:
            raise ValueError(f"segmentation.flush_persistence: {self.flush_persistence} is below merge_persistence "
                             f"{self.merge_persistence} (flush basins merge at least as readily as others)")


# The ``SegmentConfig`` fields read only with ``shapes.num_objects = estimated`` (N known ignores them: a test
# pins it), so runs with N known and N estimated may differ in them and still be compared.
ESTIMATED_COUNT_FIELDS = ("merge_persistence", "min_object_area", "flush_persistence", "flush_height", "absorb_area",
                          "explained_share", "explained_distance")


@dataclasses.dataclass(frozen=True)
class ShapeConfig:
    """The static shapes of a move: what crosses a jitted boundary has these sizes."""

    # N: with num_objects = known, the number of objects on the table (the paper's N), every slot filled; with
    # estimated, the static number of segment slots, the most objects that can be found (the rest empty).
    num_segments: int = bounded(5, ge=1)
    num_objects: ObjectCount = ObjectCount.known  # or estimated: count the objects (ObjectCount)
    points_per_segment: int = bounded(1024, ge=1)  # Ps, a segment's padded size (PointNet's input size)
    surface_points: int = bounded(16384, ge=1)  # P, the padded size of the surface extracted from the TSDF
    # Segments PointNet classifies in one pass (0 = all N): fewer keep its widest activations, [Ps, 1024] a
    # segment, live for fewer segments at once (a GPU's batch of episodes); all N is the fastest on a CPU.
    segments_per_pass: int = bounded(0, ge=0)

    def __post_init__(self) -> None:
        check_bounds(self, "shapes.")


@dataclasses.dataclass(frozen=True)
class PerceptionConfig:
    """The ``perception:`` block: everything a move's perception needs besides the camera and the table."""

    foreground: ForegroundConfig = dataclasses.field(default_factory=ForegroundConfig)
    volume: VolumeConfig = dataclasses.field(default_factory=VolumeConfig)
    segmentation: SegmentConfig = dataclasses.field(default_factory=SegmentConfig)
    shapes: ShapeConfig = dataclasses.field(default_factory=ShapeConfig)
    segmenter: Segmenter = Segmenter.jax  # or reference: scikit-learn DBSCAN + K-means on the host
    tracking: TrackingConfig = dataclasses.field(default_factory=TrackingConfig)  # the camera pose, before fusion
    # PointNet's products on an accelerator: float32 (the reference) or tf32 (tensor cores; jaxcls.precision)
    classification_precision: MatmulPrecision = MatmulPrecision.float32
    # PointNet's pooled layers at inference: xla (the reference), pallas (on a GPU one Triton kernel, the product
    # never written; in bfloat16 only; elsewhere xla) or interpreted (that kernel anywhere): pointnet.PoolingKernel
    classification_pooling: PoolingKernel = PoolingKernel.xla

    def __post_init__(self) -> None:
        check_bounds(self, "perception.")
        # The absolute thresholds are set in metres for the default volume; each holds only while it spans
        # enough voxels of this one (surface points lie about a voxel apart).
        voxel = self.volume.voxel_size
        for key, value, least, why in (
                ("foreground.table_eps", self.foreground.table_eps, 1.0, "the table's surface points lie within "
                 "a voxel of its height"),
                ("segmentation.dbscan_eps", self.segmentation.dbscan_eps, 1.5, "surface points lie about a voxel "
                 "apart: DBSCAN must bridge one"),
                ("segmentation.footprint_cell", self.segmentation.footprint_cell, 0.5, "the footprint's closing "
                 "bridges gaps of one cell")):
            if value < least * voxel:
                raise ValueError(f"perception.{key} = {value:g} m is {value / voxel:.2f} voxels of this volume "
                                 f"(volume.size {self.volume.size:g} m / resolution {self.volume.resolution} = "
                                 f"{voxel * 1e3:.1f} mm); it needs >= {least:g} voxels ({why}): set it to >= "
                                 f"{least * voxel:.4f}, or raise volume.resolution")


@struct.dataclass
class Spec:
    """What the perception stages read: static settings (hashed: a change recompiles) and the classifier's
    weights (traced leaves), in the manner of MJX's ``Model``. Build it with ``Spec.create``.

    intrinsics: the depth camera; table_height: world z of the table top, m; config: the settings;
    classifier: PointNet weights and class list, or None for a perception without classification.
    """

    intrinsics: Intrinsics = struct.field(pytree_node=False, default=Intrinsics.kinect_v1())
    table_height: float = struct.field(pytree_node=False, default=0.0)
    config: PerceptionConfig = struct.field(pytree_node=False, default=PerceptionConfig())
    classifier: Classifier | None = None

    @classmethod
    def create(cls, config: PerceptionConfig | None = None, intrinsics: Intrinsics | None = None,
               table_height: float = 0.0, classifier: Classifier | None = None) -> Spec:
        """A spec; the classifier's class list is the one its scores are in."""
        if not np.isfinite(table_height):
            raise ValueError(f"Spec: table_height must be finite, got {table_height}")
        return cls(intrinsics=intrinsics or Intrinsics.kinect_v1(), table_height=float(table_height),
                   config=config or PerceptionConfig(), classifier=classifier)

    # Derived geometry, one definition each.
    @property
    def floor(self) -> float:
        """World z at and below which points are table: table height + ``foreground.table_eps``."""
        return self.table_height + self.config.foreground.table_eps

    @property
    def roi_center(self) -> tuple[float, float, float]:
        """World centre of the cube of interest (the TSDF volume), m."""
        x, y, z = self.config.volume.center
        return (float(x), float(y), float(z) + self.table_height)

    @property
    def roi_size(self) -> float:
        """Edge of the cube of interest, m."""
        return self.config.volume.size

    @property
    def num_segments(self) -> int:
        return self.config.shapes.num_segments

    @property
    def points_per_segment(self) -> int:
        return self.config.shapes.points_per_segment

    @property
    def segmentation(self) -> SegmentConfig:
        return self.config.segmentation
