"""One move's perception, composed in one place: track -> foreground -> integrate -> extract -> segment -> classify.

``perceive(spec, state, depth, T_wc) -> state`` is the owner of the chain; every stage stays its own pure
function in its module (``tracking``, ``foreground``, ``tsdf``, ``segment``, ``pointnet``) and ``perceive`` only
composes them, so that the episode can extend a move with refinement and view selection without rewiring it.

``perceive`` is pure JAX: jit it, ``vmap`` it over episodes (``in_axes=(None, 0, 0, 0)``), scan it over
frames. ``observe`` is the host's entry: it validates the frame, then perceives. The segmenter is chosen
by ``spec.config.segmenter`` (``SEGMENTERS``): the JAX twin (the default) or scikit-learn, which runs on
the host through a callback inside the same program.

    spec = Spec.create(PerceptionConfig(), intrinsics, table_height, pointnet.load_classifier())
    state = init_state(spec)
    for depth, T_wc in frames:
        state = observe(spec, state, depth, T_wc)
    state.segments.points, state.probs          # [N, Ps, 3], [N, M]
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls.perception import foreground, pointnet, tracking, tsdf
from jaxcls.perception.segment import Segments, segment, segment_jax
from jaxcls.perception.settings import Segmenter, Spec


@struct.dataclass
class Observation:
    """What perception knows after the frames fused so far.

    volume: the TSDF (``tsdf.TSDFVolume``) of the cube of interest.
    surface: the volume's zero crossings (``tsdf.Surface``): points, normals [P, 3], mask [P].
    segments: N segments of the surface (``Segments``): points, normals [N, Ps, 3], mask [N, Ps], labels [P].
    probs: [N, M] f32 class probabilities of each segment (paper Eq. 1's softmax); M = 0 without a classifier.
    yaw: [N, M] f32 rad the yaw head's estimate per segment and class (``pointnet.predict``; 0 without a head).
    frames: [] i32 number of frames fused.
    tracking: the camera tracking's state (``tracking.Tracking``): the pose the last frame was fused at, its
    registration's outcome, frames accepted and refused, the running hand-eye estimate.
    """

    volume: tsdf.TSDFVolume
    surface: tsdf.Surface
    segments: Segments
    probs: jax.Array
    yaw: jax.Array
    frames: jax.Array
    tracking: tracking.Tracking


def empty_volume(spec: Spec) -> tsdf.TSDFVolume:
    """An unobserved TSDF cube as ``spec.config.volume`` places and sizes it (centre above the table)."""
    v = spec.config.volume
    return tsdf.create_volume(np.asarray(spec.roi_center), size=v.size, resolution=v.resolution,
                              truncation=v.truncation_voxels * v.voxel_size, storage=v.storage)


def init_state(spec: Spec) -> Observation:
    """The state before the first frame: an empty volume, empty surface and segments, uniform scores."""
    P, N, Ps = spec.config.shapes.surface_points, spec.num_segments, spec.points_per_segment
    M = len(spec.classifier.classes) if spec.classifier is not None else 0
    surface = tsdf.Surface(points=jnp.zeros((P, 3)), normals=jnp.zeros((P, 3)), mask=jnp.zeros(P, bool))
    segments = Segments(points=jnp.zeros((N, Ps, 3)), normals=jnp.zeros((N, Ps, 3)), mask=jnp.zeros((N, Ps), bool),
                        labels=jnp.full(P, -1, jnp.int32))
    return Observation(volume=empty_volume(spec), surface=surface, segments=segments,
                       probs=jnp.full((N, M), 1.0 / max(M, 1), jnp.float32), yaw=jnp.zeros((N, M), jnp.float32),
                       frames=jnp.zeros((), jnp.int32), tracking=tracking.Tracking.create(spec.config.tracking))


def fuse(spec: Spec, volume: tsdf.TSDFVolume, depth: jax.Array, T_wc: jax.Array) -> tsdf.TSDFVolume:
    """The frame's foreground integrated into ``volume`` (depth: [H, W] m, 0 = no return; T_wc: [4, 4])."""
    T_wc = jnp.asarray(T_wc, jnp.float32)
    return tsdf.integrate(volume, foreground.foreground_depth(spec, jnp.asarray(depth), T_wc), spec.intrinsics,
                          T_wc, slabs=spec.config.volume.slabs, kernel=spec.config.volume.kernel)


def classify_segments(spec: Spec, segments: Segments) -> tuple[jax.Array, jax.Array]:
    """([N, M] class probabilities, [N, M] yaw estimates, rad) of the segments by PointNet (``pointnet.predict``),
    ``shapes.segments_per_pass`` segments a pass (0: all N in one; fewer keep the network's widest activations,
    [Ps, 1024] a segment, live for fewer at once); [N, 0] both when the spec has no classifier."""
    if spec.classifier is None:
        empty = jnp.zeros((spec.num_segments, 0), jnp.float32)
        return empty, empty

    def classify(points: jax.Array, mask: jax.Array) -> tuple[jax.Array, jax.Array]:
        return pointnet.predict(spec.classifier, points, mask, spec.config.classification_precision,
                                spec.config.classification_pooling)

    per_pass = spec.config.shapes.segments_per_pass
    if per_pass == 0 or per_pass >= spec.num_segments:
        return classify(segments.points, segments.mask)
    def one(segment: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        """A segment as a batch of one (lax.map hands a pass's segments one by one to a vmapped function)."""
        probs, yaw = classify(segment[0][None], segment[1][None])
        return probs[0], yaw[0]

    return jax.lax.map(one, (segments.points, segments.mask), batch_size=per_pass)


# The move's perception in stages, each ``(spec, state, depth, T_wc) -> state``: ``observe`` folds over them;
# the episode's timed path runs them one by one with the same functions (``STAGES``).

def track(spec: Spec, state: Observation, depth: jax.Array, T_wc: jax.Array) -> tracking.Tracking:
    """The camera pose to fuse the frame at (``tracking.track``): ``T_wc`` as the robot reports it, corrected by
    the hand-eye estimate and registered to the surface fused so far (and the table plane); with
    ``tracking.mode = reported``, ``T_wc`` itself. Returns the new ``Tracking`` (its ``pose``)."""
    return _track_jit(spec, state, jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32))


@jax.jit
def _track_jit(spec: Spec, state: Observation, depth: jax.Array, T_wc: jax.Array) -> tracking.Tracking:
    """``track``'s body, one module-level jit (from Python a stage runs jitted; under a caller's jit it inlines)."""
    surface = state.surface
    return tracking.track(spec.config.tracking, state.tracking, depth, T_wc, spec.intrinsics, spec.table_height,
                          surface.points, surface.normals, surface.mask, state.frames == 0)


def reconstruct(spec: Spec, state: Observation, depth: jax.Array, T_wc: jax.Array) -> Observation:
    """Stage 1, reconstruction: the camera tracked (``track``), the frame fused into the TSDF at the tracked
    pose and the surface extracted. ``T_wc``: [4, 4] the pose the robot reports."""
    tracked = track(spec, state, depth, T_wc)
    volume = fuse(spec, state.volume, depth, tracked.pose)
    return state.replace(volume=volume, surface=tsdf.extract_surface(volume, spec.config.shapes.surface_points),
                         frames=state.frames + 1, tracking=tracked)


def reconstruct_views(spec: Spec, state: Observation, depth: jax.Array, T_wc: jax.Array, passes: int = 1
                      ) -> tuple[Observation, jax.Array]:
    """Frames fused one after another (``reconstruct`` in a ``lax.scan``): depth [K, H, W] m, T_wc [K, 4, 4] the
    reported poses. Returns the state after the last frame and the [K, 4, 4] poses the frames were fused at.

    ``passes`` > 1 (tracking and its hand-eye estimate on; static): when every frame is at hand before the
    first is fused (offline, PointNetFull), the frames are fused again from ``state``'s volume with the
    hand-eye estimate the previous pass ended with, so the early frames too are fused at poses the converged
    estimate predicts, not at poses tracked before it had seen enough frames; the last pass is returned.
    """
    if passes < 1:
        raise ValueError(f"reconstruct_views: passes must be >= 1, got {passes}")

    def fuse(obs: Observation, frame: tuple[jax.Array, jax.Array]) -> tuple[Observation, jax.Array]:
        obs = reconstruct(spec, obs, *frame)
        return obs, obs.tracking.pose

    def one_pass(carry, _):  # from ``state`` with the hand-eye estimate the last pass ended with
        hand_eye = carry[0]
        out, poses = jax.lax.scan(fuse, state.replace(tracking=state.tracking.replace(hand_eye=hand_eye)),
                                  (depth, T_wc))
        return (out.tracking.hand_eye, out, poses), None

    tracked = spec.config.tracking
    count = passes if tracked.on and tracked.hand_eye else 1
    # The passes as a scan too: the frames' scan body is compiled once, whatever ``passes``.
    init = (state.tracking.hand_eye, state, jnp.zeros(jnp.shape(T_wc), jnp.float32))
    (_, out, poses), _ = jax.lax.scan(one_pass, init, None, length=count)
    return out, poses


SEGMENTERS = {Segmenter.jax: segment_jax, Segmenter.reference: segment}  # (spec, points, normals, mask) -> Segments


def segmentation(spec: Spec, state: Observation, depth: jax.Array | None = None,
                 T_wc: jax.Array | None = None) -> Observation:
    """Stage 2, segmentation of the surface by ``spec.config.segmenter`` (``SEGMENTERS``)."""
    segment_fn = SEGMENTERS[spec.config.segmenter]
    return state.replace(segments=segment_fn(spec, state.surface.points, state.surface.normals, state.surface.mask))


def classification(spec: Spec, state: Observation, depth: jax.Array | None = None,
                   T_wc: jax.Array | None = None) -> Observation:
    """Stage 3, classification: PointNet's calibrated scores (and yaw estimates) of the segments."""
    probs, yaw = classify_segments(spec, state.segments)
    return state.replace(probs=probs, yaw=yaw)


STAGES = (("reconstruction", reconstruct), ("segmentation", segmentation), ("classification", classification))


def check_observation_inputs(spec: Spec, depth: np.ndarray | jax.Array, T_wc: np.ndarray | jax.Array) -> None:
    """Host-side validation of a frame (shapes, a rigid finite pose), with errors naming what is wrong."""
    foreground.check_depth_shape(spec, depth, T_wc, "observe")
    tsdf.check_frame(depth, spec.intrinsics, T_wc)


def perceive(spec: Spec, state: Observation, depth: jax.Array, T_wc: jax.Array) -> Observation:
    """One move's perception as a pure function (jit it, vmap it, scan it): the ``STAGES`` in order.

    depth: [H, W] z-depth, m (0 = no return); T_wc: [4, 4] camera-to-world pose of the frame. Only the shapes
    are checked (they are static); ``observe`` is the host's entry, which validates the frame first.
    """
    foreground.check_depth_shape(spec, depth, T_wc, "observe")
    for _, stage in STAGES:
        state = stage(spec, state, depth, T_wc)
    return state


def observe(spec: Spec, state: Observation, depth: np.ndarray | jax.Array, T_wc: np.ndarray | jax.Array
            ) -> Observation:
    """One move's perception from the host: the frame validated (``check_observation_inputs``: shapes, a
    rigid finite pose, errors naming the problem), then ``perceive``: fuse the frame's foreground, extract
    the surface, segment it, classify. Returns a new state.

    The stages run one by one, each its own module-level jit: on the CPU as fast as a hand-wired chain,
    while one XLA program of foreground + integration is ~1.8 ms slower there (benchmarks/ab_move.py).
    Under a caller's jit/vmap (the GPU's shape) use ``perceive``: the stages trace into one program.
    """
    check_observation_inputs(spec, depth, T_wc)
    return perceive(spec, state, jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32))
