"""Fuse posed depth maps into a truncated signed distance volume and read its surface back (paper Sec. 3.1).

The camera poses are known (robot kinematics), so each depth map is fused with a projective TSDF update
(Curless & Levoy; KinectFusion): every voxel centre is projected into the image, the nearest pixel's depth
gives the signed distance along the camera's z axis, truncated and averaged with the voxel's running
weight. One integration is a vectorised pass over the voxels (no scatter over pixels; or ``slabs`` passes along
x, updated in place, so that its temporaries span a slab), with static shapes, so it jits, scans over frames
and vmaps over episodes.

Conventions (docs/ARCHITECTURE.md): metres; world z up; OpenCV camera, pose ``T_wc`` camera-to-world; depth is z-depth,
0 = no return. Voxel ``(i, j, k)`` has its centre at ``origin + voxel_size * (i, j, k)``. Stored TSDF
values are signed distance / truncation in [-1, 1], positive in front of the surface (free space), 1 where
unobserved; ``weight`` 0 marks unobserved voxels.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax import custom_batching
from jax.experimental import pallas as pl

from jaxcls import geometry
from jaxcls.geometry import Intrinsics
from jaxcls.math import normalize, safe_norm
from jaxcls.perception import kernels

# Voxel pairs whose values are this close to +-1 sit on a truncation edge, not on the surface.
_TRUNCATION_EDGE = 0.99
# A compact volume's tsdf values are int16 multiples of 1 / COMPACT_SCALE.
COMPACT_SCALE = 32767.0
# A compact volume's weights saturate here (uint8): a voxel seen more often keeps a running average over its
# last ~255 observations (KinectFusion's weight cap); episodes fuse 10 frames, PointNetFull 100.
MAX_COMPACT_WEIGHT = 255


class VolumeStorage(enum.StrEnum):
    """How a volume's voxels are stored (``perception.volume.storage``): ``float32``, the reference (tsdf and
    weight float32, 8 bytes a voxel; differentiable w.r.t. the depth); ``compact``, tsdf as int16 fixed point
    (value x ``COMPACT_SCALE``, rounded) and weight uint8 saturating at ``MAX_COMPACT_WEIGHT`` (3 bytes a voxel:
    a 128^3 volume is 6.3 MB against 16.8 MB, what bounds how many episodes fit a GPU). Every update is
    computed in float32 and rounded once into the storage: a value moves by < 2e-5 of the truncation (0.4 um
    at the default 19 mm) a rounding, the same everywhere in [-1, 1], so a long running average does not stall
    the way float16's coarser steps near +-1 would."""

    float32 = "float32"
    compact = "compact"

    @property
    def dtypes(self) -> tuple[jnp.dtype, jnp.dtype]:
        """(tsdf dtype, weight dtype)."""
        return (jnp.float32, jnp.float32) if self is VolumeStorage.float32 else (jnp.int16, jnp.uint8)

    def encode(self, values: jax.Array, rounding: Callable[[jax.Array], jax.Array] = jnp.round) -> jax.Array:
        """float32 tsdf values in [-1, 1] as stored (a compact volume's rounded by ``rounding``: to nearest, ties
        to even; ``round_half_even`` in a Pallas kernel)."""
        if self is VolumeStorage.float32:
            return values.astype(jnp.float32)
        return rounding(values * COMPACT_SCALE).astype(jnp.int16)

    def decode(self, stored: jax.Array) -> jax.Array:
        """Stored tsdf values as float32 in [-1, 1]."""
        if self is VolumeStorage.float32:
            return stored
        return stored.astype(jnp.float32) * (1.0 / COMPACT_SCALE)


# Default truncation band, in voxels: wide enough to average a few voxels across the surface, narrow
# enough not to merge the near sides of objects packed a couple of centimetres apart.
_DEFAULT_TRUNCATION_VOXELS = 4.0


@struct.dataclass
class TSDFVolume:
    """A cube of voxels. Traced: ``tsdf``, ``weight``, ``origin``; static: the grid spacing and band.

    tsdf: [X, Y, Z] signed distance / truncation in [-1, 1]; 1 where unobserved (f32, or f16 when compact).
    weight: [X, Y, Z] accumulated observation weights; 0 = unobserved (f32, or u8 when compact:
    ``VolumeStorage``).
    origin: [3] f32 world position (m) of the centre of voxel (0, 0, 0).
    voxel_size: edge of a voxel, m.
    truncation: half-width of the band of observed signed distances, m.
    """

    tsdf: jax.Array
    weight: jax.Array
    origin: jax.Array
    voxel_size: float = struct.field(pytree_node=False)
    truncation: float = struct.field(pytree_node=False)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.tsdf.shape)

    @property
    def storage(self) -> VolumeStorage:
        return VolumeStorage.float32 if self.weight.dtype == jnp.float32 else VolumeStorage.compact

    @property
    def values(self) -> jax.Array:
        """[X, Y, Z] f32 the tsdf values in [-1, 1], whatever the storage."""
        return self.storage.decode(self.tsdf)


@struct.dataclass
class Surface:
    """Zero-crossing points of a volume, padded to a static size.

    points: [P, 3] f32 world positions, m (0 where ``mask`` is False).
    normals: [P, 3] f32 unit outward normals (pointing to free space; 0 where ``mask`` is False).
    mask: [P] bool, True for real points.
    """

    points: jax.Array
    normals: jax.Array
    mask: jax.Array


def create_volume(center: np.ndarray | jax.Array, size: float = 0.6, resolution: int = 128,
                  truncation: float | None = None, storage: VolumeStorage | str = VolumeStorage.float32
                  ) -> TSDFVolume:
    """An empty (unobserved) cube of ``resolution``^3 voxels and edge ``size`` m, centred on ``center: [3]``.

    The cube is the paper's space of interest around the objects; ``truncation`` defaults to 4 voxels;
    ``storage`` (``VolumeStorage``) sets the voxels' types.
    """
    weight_dtype = VolumeStorage(storage).dtypes[1]
    if resolution < 2 or size <= 0:
        raise ValueError(f"create_volume: need resolution >= 2 and size > 0, got {resolution}, {size}")
    center = np.asarray(center, np.float64)
    if center.shape != (3,) or not np.all(np.isfinite(center)):
        raise ValueError(f"create_volume: center must be a finite [3] point, got {center!r}")
    voxel_size = float(size) / resolution
    truncation = _DEFAULT_TRUNCATION_VOXELS * voxel_size if truncation is None else float(truncation)
    if truncation <= 0:
        raise ValueError(f"create_volume: truncation must be > 0, got {truncation}")
    origin = center - 0.5 * size + 0.5 * voxel_size
    shape = (resolution,) * 3
    return TSDFVolume(tsdf=VolumeStorage(storage).encode(jnp.ones(shape, jnp.float32)),
                      weight=jnp.zeros(shape, weight_dtype), origin=jnp.asarray(origin, jnp.float32),
                      voxel_size=voxel_size, truncation=truncation)


def check_frame_shapes(depth: np.ndarray | jax.Array, intrinsics: Intrinsics, T_wc: np.ndarray | jax.Array,
                       where: str = "check_frame") -> None:
    """The shapes of a frame (static, so checked under jit too): depth [H, W] of ``intrinsics``, T_wc [4, 4]."""
    expected = (intrinsics.height, intrinsics.width)
    shape = tuple(np.shape(depth))
    if shape != expected:
        raise ValueError(f"{where}: depth has shape {shape}, the intrinsics expect [H, W] = {list(expected)}")
    if tuple(np.shape(T_wc)) != (4, 4):
        raise ValueError(f"{where}: pose T_wc must be [4, 4], got shape {tuple(np.shape(T_wc))}")


def check_frame(depth: np.ndarray | jax.Array, intrinsics: Intrinsics, T_wc: np.ndarray | jax.Array) -> None:
    """Host-side validation of one frame before it reaches the jitted ``integrate`` (which cannot raise).

    depth: [H, W] z-depth, m; T_wc: [4, 4] rigid camera-to-world pose. Raises ValueError naming the problem.
    """
    check_frame_shapes(depth, intrinsics, T_wc)
    if not bool(geometry.is_rigid(np.asarray(T_wc))):
        raise ValueError("check_frame: pose T_wc is not rigid (finite, orthonormal rotation with det +1, "
                         f"last row 0 0 0 1):\n{np.asarray(T_wc)}")


def slabs_in_place(values: Callable[..., tuple[jax.Array, ...]], start: int | jax.Array, size: int,
                   arrays: tuple[jax.Array, ...], *operands: jax.Array) -> tuple[jax.Array, ...]:
    """``arrays`` (each [X, ...]) with their slabs [start, start + size) along axis 0 replaced, in place, by
    ``values(start, *slabs, *operands)`` (each slab [size, ...]; returns one new slab an array). ``arrays`` and
    ``operands`` are arrays (not pytrees), and everything traced that ``values`` reads is passed in ``operands``:
    ``values`` must not close over traced values (the batching rule below re-traces it apart from its caller).

    The same as ``dynamic_slice`` and ``dynamic_update_slice`` of each array, and differentiable like them (its
    derivatives are theirs), but batched otherwise: under ``vmap`` with ``start`` unbatched (a loop's counter),
    the slabs are sliced and written along the batch's axis 1 (an unbatched array first broadcast to the batch)
    and ``values`` is vmapped; a batched ``start`` takes the general form. JAX batches ``dynamic_slice`` as a
    gather and ``dynamic_update_slice`` as a scatter, which XLA turned into the slab copied out twice (differently
    bounds-checked) and written back: the batched fusion's largest kernels on a GPU after its gather (BENCHMARKS.md,
    "The fusion's slabs batched in place"). Only the innermost ``vmap`` gets this form: an outer one batches the
    rule's slice and update as JAX does (the project runs one level).
    """
    def plain(start: jax.Array, arrays: tuple[jax.Array, ...], operands: tuple[jax.Array, ...]) -> tuple:
        slabs = [jax.lax.dynamic_slice_in_dim(a, start, size, 0) for a in arrays]
        new = values(start, *slabs, *operands)
        return tuple(jax.lax.dynamic_update_slice_in_dim(a, b, start, 0) for a, b in zip(arrays, new, strict=True))

    @custom_batching.custom_vmap
    def batched(start: jax.Array, arrays: tuple[jax.Array, ...], operands: tuple[jax.Array, ...]) -> tuple:
        return plain(start, arrays, operands)

    @batched.def_vmap
    def _(axis_size: int, in_batched: list, start: jax.Array, arrays: tuple[jax.Array, ...],
          operands: tuple[jax.Array, ...]) -> tuple[tuple, tuple]:
        start_batched, arrays_batched, operands_batched = in_batched
        out_batched = (True,) * len(arrays)

        def axes(flags: tuple[bool, ...]) -> tuple[int | None, ...]:
            return tuple(0 if b else None for b in flags)

        if start_batched:  # a slab of its own an element: the general (gather and scatter) form
            return jax.vmap(plain, in_axes=(0, axes(arrays_batched), axes(operands_batched)))(
                start, arrays, operands), out_batched
        arrays = [a if b else jnp.broadcast_to(a, (axis_size, *a.shape))
                  for a, b in zip(arrays, arrays_batched, strict=True)]
        slabs = [jax.lax.dynamic_slice_in_dim(a, start, size, 1) for a in arrays]
        new = jax.vmap(values, in_axes=(None, *(0,) * len(arrays), *axes(operands_batched)))(start, *slabs, *operands)
        return tuple(jax.lax.dynamic_update_slice_in_dim(a, b, start, 1)
                     for a, b in zip(arrays, new, strict=True)), out_batched

    @jax.custom_jvp
    def differentiable(start: jax.Array, arrays: tuple[jax.Array, ...], operands: tuple[jax.Array, ...]) -> tuple:
        return batched(start, arrays, operands)

    @differentiable.defjvp
    def _(primals: tuple, tangents: tuple) -> tuple:
        return jax.jvp(plain, primals, tangents)

    return differentiable(jnp.asarray(start), tuple(arrays), operands)


class FusionKernel(enum.StrEnum):
    """How ``integrate`` updates the voxels (``perception.volume.kernel``): ``xla``, vectorised JAX over the volume
    (or its ``slabs``), the reference; ``pallas``, on a GPU one Pallas kernel over blocks of voxels
    (``FusionBlocks``) reading the volume and writing it in place, no temporaries in memory (Triton), on any other
    platform ``xla`` (``kernels.pallas_call``); ``interpreted``, that kernel interpreted on every platform (slow: to
    check the kernel off a GPU). The kernel is not differentiable; a volume whose voxel count has no power-of-two
    factor of 128 or more takes ``xla``. Both compute the same float32 arithmetic (``_voxel_update``). A limit of
    JAX's Triton lowering: a compact volume's uint8 weights batched 1,025 to 2,048 to a device (2^31 to 2^32 bytes
    of 128^3 volumes) are addressed with 32-bit offsets that overflow; ``check_kernel_batch`` refuses that batch."""

    xla = "xla"
    pallas = "pallas"
    interpreted = "interpreted"


def check_kernel_batch(kernel: FusionKernel, storage: VolumeStorage, resolution: int, volumes: int,
                       platform: str) -> None:
    """Raise ValueError where ``volumes`` volumes of ``resolution``^3 voxels fused together on one device of
    ``platform`` (``jax.Device.platform``) by the Pallas kernel compiled there would overflow its 32-bit offsets
    (``FusionKernel``: a uint8 weights array of more than 2^31 and at most 2^32 bytes; only a GPU compiles it)."""
    if (FusionKernel(kernel) is FusionKernel.pallas and VolumeStorage(storage) is VolumeStorage.compact
            and platform == "gpu"):
        size = volumes * resolution ** 3  # (bytes of the batch's weights)
        if 2 ** 31 < size <= 2 ** 32:
            raise ValueError(f"perception.volume.kernel=pallas: {volumes} compact {resolution}^3 volumes on one "
                             f"device ({size} bytes of weights) overflow the kernel's 32-bit offsets (JAX's Triton "
                             "lowering); run at most 2^31 bytes or more than 2^32 a device, or volume.kernel=xla")


def round_half_even(x: jax.Array) -> jax.Array:
    """``jnp.round`` (to the nearest integer, ties to even) of float32 ``x`` from floor and compares, the same value
    for every finite one (a zero's sign aside: -0.4 gives +0): what a Pallas kernel on a GPU lowers (Triton has
    no rounding op)."""
    r = jnp.floor(x)
    frac = x - r  # (exact)
    odd = r - 2.0 * jnp.floor(r * 0.5) == 1.0  # (exact below 2^24; above, every float32 is even)
    return jnp.where((frac > 0.5) | ((frac == 0.5) & odd), r + 1.0, r)


def _camera_coords(base: Callable[[int], jax.Array], step: Callable[[int, int], jax.Array], i: jax.Array,
                   j: jax.Array, k: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Camera-frame (x, y, z) of the voxel centres at indices (i, j, k) (float32, broadcast together), affine in
    them: c = R^T (origin - t) + vs R^T[:, a] idx_a; ``base(row)``: the first term's row, ``step(row, a)``: the
    step of one voxel along world axis a."""
    def row(r: int) -> jax.Array:
        return base(r) + step(r, 0) * i + step(r, 1) * j + step(r, 2) * k

    return row(0), row(1), row(2)


def _voxel_update(coords: tuple[jax.Array, jax.Array, jax.Array], tsdf: jax.Array, weight: jax.Array,
                  lookup: Callable[[jax.Array], jax.Array], intrinsics: Intrinsics, truncation: float,
                  storage: VolumeStorage, rounding: Callable[[jax.Array], jax.Array] = jnp.round
                  ) -> tuple[jax.Array, jax.Array]:
    """New stored (tsdf, weight) of voxels at camera coordinates ``coords`` from their stored ones (any shape, the
    same): each voxel projected to its nearest pixel, whose depth (``lookup(flat pixel index)``; 0 = no return)
    gives the observed signed distance; updated where observed and not behind the surface by more than
    ``truncation`` m. In float32 whatever the storage; a compact volume's weight saturates (MAX_COMPACT_WEIGHT).
    ``rounding``: to the nearest pixel and fixed-point step, ties to even (``jnp.round``, or ``round_half_even``)."""
    H, W = intrinsics.height, intrinsics.width
    x, y, z = coords
    in_front = z > 1e-6
    inv_z = 1.0 / jnp.where(in_front, z, 1.0)
    u, v = (rounding(c) for c in intrinsics.project(x, y, inv_z))
    inside = in_front & (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    d = lookup(jnp.where(inside, v * W + u, 0.0).astype(jnp.int32))
    sdf = d - z
    update = inside & (d > 0) & (sdf >= -truncation)
    observed = jnp.clip(sdf * (1.0 / truncation), -1.0, 1.0)
    old_tsdf, old_weight = storage.decode(tsdf), weight.astype(jnp.float32)
    new_weight = old_weight + update.astype(jnp.float32)
    if storage is VolumeStorage.compact:
        new_weight = jnp.minimum(new_weight, MAX_COMPACT_WEIGHT)
    new_tsdf = jnp.where(update, old_tsdf + (observed - old_tsdf) / jnp.maximum(new_weight, 1.0), old_tsdf)
    return storage.encode(new_tsdf, rounding), new_weight.astype(weight.dtype)


class FusionBlocks(NamedTuple):
    """The Pallas fusion's blocks (``FusionKernel.pallas``; a GPU's speed, not its values, depends on them):
    ``voxels`` consecutive voxels a program (a power of two of 128 or more: Triton's blocks; a volume whose voxel
    count it does not divide takes the largest power of two that does), ``warps`` a program (Triton) and ``steps``
    a program's voxels are updated in, one part after another (a loop Triton may pipeline: the next part's loads
    beside this one's arithmetic)."""

    voxels: int = 2048
    warps: int = 4
    steps: int = 1


# The fusion's blocks wherever it runs (a default argument: edit it here; benchmarks/pallas_kernels.py --fusion-blocks
# compares others)
FUSION_BLOCKS = FusionBlocks()


def _fuse_vectorised(volume: TSDFVolume, depth: jax.Array, intrinsics: Intrinsics, base: jax.Array,
                     step: jax.Array, slabs: int) -> tuple[jax.Array, jax.Array]:
    """``FusionKernel.xla``: (tsdf, weight) of ``volume`` updated by vectorised JAX, in ``slabs`` passes along x
    (in place, slab after slab: the temporaries span a slab). depth: [H W] m (0 = no return), flattened; base:
    [3], step: [3, 3] as in ``_camera_coords``."""
    X, Y, Z = volume.shape
    if X % slabs:
        raise ValueError(f"integrate: slabs ({slabs}) must divide the volume's {X} voxels along x")
    sx = X // slabs

    def update_slab(start: int | jax.Array, tsdf: jax.Array, weight: jax.Array, depth: jax.Array, base: jax.Array,
                    step: jax.Array) -> tuple[jax.Array, jax.Array]:
        """New stored values of voxels x in [start, start + sx) from their old ones (tsdf, weight: [sx, Y, Z]):
        the temporaries are a slab's, not the volume's (in float32)."""
        i = (start + jnp.arange(sx)).astype(jnp.float32)[:, None, None]
        j = jnp.arange(Y, dtype=jnp.float32)[None, :, None]
        k = jnp.arange(Z, dtype=jnp.float32)[None, None, :]
        coords = _camera_coords(lambda r: base[r], lambda r, a: step[r, a], i, j, k)
        return _voxel_update(coords, tsdf, weight, lambda pixel: depth.at[pixel].get(mode="promise_in_bounds"),
                             intrinsics, volume.truncation, volume.storage)

    if slabs == 1:
        return update_slab(0, volume.tsdf, volume.weight, depth, base, step)

    def in_place(n: jax.Array, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        return slabs_in_place(update_slab, n * sx, sx, carry, depth, base, step)

    return jax.lax.fori_loop(0, slabs, in_place, (volume.tsdf, volume.weight))


def _fuse_in_kernel(volume: TSDFVolume, depth: jax.Array, intrinsics: Intrinsics, base: jax.Array,
                    step: jax.Array, slabs: int, interpreted: bool,
                    blocks: FusionBlocks = FUSION_BLOCKS) -> tuple[jax.Array, jax.Array] | None:
    """``FusionKernel.pallas`` / ``interpreted``: (tsdf, weight) of ``volume`` updated by one Pallas kernel,
    ``blocks.voxels`` consecutive voxels (x-major) a program, in place (off a GPU, ``_fuse_vectorised`` in
    ``slabs`` passes, unless ``interpreted``); None where the volume's voxel count has no power-of-two factor of
    at least 128 (the caller fuses with XLA). depth: [H W] m (0 = no return), flattened; base: [3], step: [3, 3]
    as in ``_camera_coords``. Under vmap, the batch is a grid axis of the same kernel."""
    X, Y, Z = volume.shape
    count = X * Y * Z
    if not (kernels.power_of_two(blocks.voxels, 128) and all(map(kernels.power_of_two, blocks))):
        raise ValueError(f"integrate: the fusion kernel's blocks {blocks} need powers of two (128 or more voxels)")
    block = math.gcd(count, blocks.voxels)
    if block < 128:
        return None
    part = max(block // blocks.steps, 128)  # voxels a step (a power of two)
    params = jnp.concatenate([base, step.reshape(-1), jnp.zeros(4, jnp.float32)])  # [16]: base, step row-major
    storage = volume.storage

    def kernel(params_ref, depth_ref, tsdf_ref, weight_ref, tsdf_out, weight_out) -> None:  # (Pallas refs)
        start = pl.program_id(0) * block  # (read here, not in the loop: the interpreter substitutes it only here)

        def update(first: jax.Array | int, at: slice | pl.Slice) -> None:  # the block's voxels first + [0, part)
            voxel = start + first + jax.lax.iota(jnp.int32, part)  # (flat index, x-major)
            i = (voxel // (Y * Z)).astype(jnp.float32)
            j = (voxel // Z % Y).astype(jnp.float32)
            k = (voxel % Z).astype(jnp.float32)
            coords = _camera_coords(lambda r: params_ref[r], lambda r, a: params_ref[3 + 3 * r + a], i, j, k)
            tsdf_out[at], weight_out[at] = _voxel_update(coords, tsdf_ref[at], weight_ref[at],
                                                         lambda pixel: depth_ref[pixel], intrinsics,
                                                         volume.truncation, storage, round_half_even)

        if part == block:
            update(0, slice(None))
        else:
            def step(t: jax.Array, carry: None) -> None:
                update(t * part, pl.ds(t * part, part))

            jax.lax.fori_loop(0, block // part, step, None)

    def vectorised(params: jax.Array, depth: jax.Array, tsdf: jax.Array,
                   weight: jax.Array) -> tuple[jax.Array, jax.Array]:  # (the kernel's arguments and results)
        flat = volume.replace(tsdf=tsdf.reshape(volume.shape), weight=weight.reshape(volume.shape))
        fused = _fuse_vectorised(flat, depth, intrinsics, params[:3], params[3:12].reshape(3, 3), slabs)
        return fused[0].reshape(-1), fused[1].reshape(-1)

    voxels = pl.BlockSpec((block,), lambda n: (n,))
    whole = [pl.BlockSpec((a.size,), lambda n: (0,)) for a in (params, depth)]
    tsdf, weight = kernels.pallas_call(
        kernel, fallback=None if interpreted else vectorised, num_warps=blocks.warps, grid=(count // block,),
        in_specs=[*whole, voxels, voxels], out_specs=[voxels, voxels],
        out_shape=[jax.ShapeDtypeStruct((count,), a.dtype) for a in (volume.tsdf, volume.weight)],
        input_output_aliases={2: 0, 3: 1}, name="tsdf_fusion")(
            params, depth, volume.tsdf.reshape(-1), volume.weight.reshape(-1))
    return tsdf.reshape(volume.shape), weight.reshape(volume.shape)


def _integrate(volume: TSDFVolume, depth: jax.Array, intrinsics: Intrinsics, T_wc: jax.Array,
               max_depth: float | None, slabs: int = 1, kernel: FusionKernel = FusionKernel.xla,
               blocks: FusionBlocks = FUSION_BLOCKS) -> TSDFVolume:
    """Unjitted body of ``integrate`` (scanned by ``integrate_frames``)."""
    H, W = intrinsics.height, intrinsics.width
    if tuple(depth.shape) != (H, W) or tuple(T_wc.shape) != (4, 4):
        raise ValueError(f"integrate: need depth [H, W] = {[H, W]} and T_wc [4, 4], got shapes "
                         f"{tuple(depth.shape)} and {tuple(T_wc.shape)}")
    depth = jnp.asarray(depth, jnp.float32)
    T_wc = jnp.asarray(T_wc, jnp.float32)
    # Bad pixels (NaN, inf, <= 0, beyond max_depth) become "no return"; the double where keeps gradients finite.
    good = jnp.isfinite(depth) & (depth > 0)
    if max_depth is not None:
        good &= depth <= max_depth
    depth = jnp.where(good, depth, 0.0).reshape(-1)

    R, t = T_wc[:3, :3], T_wc[:3, 3]
    base = R.T @ (volume.origin - t)
    step = volume.voxel_size * R.T  # column a: camera-frame step of one voxel along world axis a
    kernel = FusionKernel(kernel)
    fused = None
    if kernel is not FusionKernel.xla:
        fused = _fuse_in_kernel(volume, depth, intrinsics, base, step, slabs, kernel is FusionKernel.interpreted,
                                blocks)
    if fused is None:
        fused = _fuse_vectorised(volume, depth, intrinsics, base, step, slabs)
    return volume.replace(tsdf=fused[0], weight=fused[1])


_integrate_jit = jax.jit(_integrate, static_argnames=("intrinsics", "max_depth", "slabs", "kernel", "blocks"))


def integrate(volume: TSDFVolume, depth: jax.Array, intrinsics: Intrinsics, T_wc: jax.Array,
              max_depth: float | None = None, slabs: int = 1,
              kernel: FusionKernel = FusionKernel.xla, blocks: FusionBlocks = FUSION_BLOCKS) -> TSDFVolume:
    """Fuse one depth map: projective TSDF with a running average of weight-1 observations.

    depth: [H, W] z-depth, m (0, negative, NaN or inf = no return; returns beyond ``max_depth`` m are
    dropped); T_wc: [4, 4] camera-to-world. Voxels in front of the observed surface, or behind it by less
    than the truncation, are updated; the others keep their value. Differentiable w.r.t. ``depth``.
    ``slabs`` (static; divides the voxels along x): the update in that many passes over slabs along x, the
    same values, its temporaries a slab's (``perception.volume.slabs``). ``kernel`` (static,
    ``perception.volume.kernel``): vectorised JAX (``xla``) or, on a GPU, a Pallas kernel updating the volume in
    place (``pallas``: no temporaries; not differentiable; ``FusionKernel``) over ``blocks`` (static;
    ``FusionBlocks``); ``slabs`` must divide the volume with either (``pallas`` off a GPU fuses in them).

    Pure and jit-able (a module-level jit: called under another jit it inlines); it cannot raise on values,
    so a host frame is validated first with ``check_frame`` (shapes, a rigid finite pose), as
    ``observation.observe`` does (the shapes, being static, are checked here).
    """
    check_frame_shapes(depth, intrinsics, T_wc, "integrate")
    return _integrate_jit(volume, depth, intrinsics, T_wc, max_depth, slabs, FusionKernel(kernel), blocks)


@functools.partial(jax.jit, static_argnames=("intrinsics", "max_depth"))
def integrate_frames(volume: TSDFVolume, depths: jax.Array, intrinsics: Intrinsics, T_wcs: jax.Array,
                     max_depth: float | None = None) -> TSDFVolume:
    """Fuse frames in order (``lax.scan`` of ``integrate``). depths: [T, H, W] m; T_wcs: [T, 4, 4]."""
    def body(vol: TSDFVolume, frame: tuple[jax.Array, jax.Array]) -> tuple[TSDFVolume, None]:
        return _integrate(vol, frame[0], intrinsics, frame[1], max_depth), None

    volume, _ = jax.lax.scan(body, volume, (depths, T_wcs))
    return volume


def _gradient_at(tsdf: jax.Array, idx: jax.Array, storage: VolumeStorage) -> jax.Array:
    """[P, 3] central-difference TSDF gradient (per voxel) at integer voxel indices ``idx: [P, 3]`` of the stored
    values ``tsdf`` (``storage``).

    One-sided at the border of the grid.
    """
    dims = jnp.asarray(tsdf.shape, jnp.int32)
    grads = []
    for a in range(3):
        e = jnp.zeros(3, jnp.int32).at[a].set(1)
        hi = jnp.minimum(idx + e, dims - 1)
        lo = jnp.maximum(idx - e, 0)
        f_hi = storage.decode(tsdf[hi[:, 0], hi[:, 1], hi[:, 2]])
        f_lo = storage.decode(tsdf[lo[:, 0], lo[:, 1], lo[:, 2]])
        grads.append((f_hi - f_lo) / jnp.maximum(hi[:, a] - lo[:, a], 1).astype(jnp.float32))
    return jnp.stack(grads, axis=-1)


def _pack_rows(bits: jax.Array) -> jax.Array:
    """[X, Y, ceil(Z / 32)] u32 words of ``bits: [X, Y, Z]`` bool along z (bit b of word w is z = 32 w + b)."""
    X, Y, Z = bits.shape
    bits = jnp.pad(bits, ((0, 0), (0, 0), (0, -Z % 32))).reshape(X, Y, -1, 32).astype(jnp.uint32)
    return jnp.sum(bits << jnp.arange(32, dtype=jnp.uint32), axis=-1, dtype=jnp.uint32)


def _next_voxel(words: jax.Array, axis: int) -> jax.Array:
    """Row words (``_pack_rows``) of each voxel's neighbour one step further along ``axis`` (0 past the end)."""
    if axis == 2:  # within a row: the bit above, the lowest bit of the next word carried into bit 31
        carry = jnp.pad(words[:, :, 1:], ((0, 0), (0, 0), (0, 1))) << 31
        return (words >> 1) | carry
    pad = [(0, 0)] * 3
    pad[axis] = (0, 1)
    return jnp.pad(jax.lax.slice_in_dim(words, 1, words.shape[axis], axis=axis), pad)


def _crossing_words(f: jax.Array, w: jax.Array, weight_threshold: float | jax.Array,
                    storage: VolumeStorage = VolumeStorage.float32) -> jax.Array:
    """[3, X, Y, ceil(Z / 32)] u32: bit of voxel p along axis a is set where the edge p -> p + e_a crosses zero.

    Both ends must be trusted (weight >= threshold, |f| off the truncation edge) and of opposite signs. The
    two sign masks are packed once; the three axes' edges are then word operations on 32 voxels at a time.
    """
    f, w = storage.decode(f), w.astype(jnp.float32)  # any storage (``VolumeStorage``), fused into the packing
    ok = (w >= weight_threshold) & (jnp.abs(f) < _TRUNCATION_EDGE)
    pos, neg = _pack_rows(ok & (f >= 0)), _pack_rows(ok & (f < 0))
    return jnp.stack([(pos & _next_voxel(neg, a)) | (neg & _next_voxel(pos, a)) for a in range(3)])


def _word_of_slot_search(first_past: jax.Array, size: int) -> jax.Array:
    """[size] i32: for each slot p, #{w : first_past[w] <= p} (``first_past: [M]`` non-decreasing), by a binary
    search per slot: cheap on a CPU (log M steps of ``size`` reads)."""
    return jnp.searchsorted(first_past, jnp.arange(size, dtype=first_past.dtype), side="right")


def _word_of_slot_scatter(first_past: jax.Array, size: int) -> jax.Array:
    """``_word_of_slot_search``'s slots, by one pass over the words: the last word of each run of equal
    ``first_past`` (the only one a slot can need) writes w + 1 at slot ``first_past[w]`` (a slot gets one write at
    most: no atomics contend; the others dropped out of bounds), then a running max over the slots. On a GPU one
    streaming pass instead of log M dependent rounds of scattered reads; on a CPU XLA's scatter is a serial loop
    (~5 ms against ~2 ms for 196,608 words on the 2-core CPU)."""
    M = first_past.shape[0]
    last = jnp.concatenate([first_past[1:] != first_past[:-1], jnp.ones(1, bool)])
    target = jnp.where(last, first_past, size)  # (size: out of bounds, dropped)
    hits = jnp.zeros(size, jnp.int32).at[target].max(jnp.arange(1, M + 1, dtype=jnp.int32), mode="drop")
    return jax.lax.cummax(hits)


def _select_bits(words: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """Indices of up to ``size`` set bits of ``words: [M]`` u32: ([size] i32 bit indices, [size] bool valid).

    A compaction that is cheap on CPUs, where a cumulative sum or a binary search per voxel is not:
    popcounts and their cumulative sum run over words; slot p takes the set bit of rank r(p) = floor(p s)
    (s = max(1, total / size): all set bits in order when they fit, else ``size`` of them evenly spread).
    Its word is found from where each word's bits end in slot units, per slot, not per voxel (a histogram
    would make the many empty words contend for one counter on a GPU): by a binary search on a CPU
    (``_word_of_slot_search``), by one pass over the words elsewhere (``_word_of_slot_scatter``; the same
    words); its bit by counting bits inside the word.
    """
    counts = jax.lax.population_count(words).astype(jnp.int32)
    cum = jnp.cumsum(counts)  # inclusive
    total = cum[-1]
    stride = jnp.maximum(total.astype(jnp.float32) / size, 1.0)
    slot = jnp.arange(size, dtype=jnp.int32)
    rank = jnp.floor(slot.astype(jnp.float32) * stride).astype(jnp.int32)
    # Word of slot p = #{w : cum[w] <= r(p)} = #{w : first slot past word w <= p}.
    first_past = jnp.minimum(jnp.ceil(cum.astype(jnp.float32) / stride), size).astype(jnp.int32)
    word = jax.lax.platform_dependent(first_past, cpu=functools.partial(_word_of_slot_search, size=size),
                                      default=functools.partial(_word_of_slot_scatter, size=size))
    word = jnp.minimum(word, words.shape[0] - 1)
    count = counts[word]
    within = jnp.clip(rank - (cum[word] - count), 0, jnp.maximum(count - 1, 0))  # rank inside the word
    below = jnp.uint32(0xFFFFFFFF) >> (31 - jnp.arange(32, dtype=jnp.uint32))  # bits 0..b set
    prefix = jax.lax.population_count(words[word][:, None] & below).astype(jnp.int32)  # [size, 32]
    bit = jnp.sum(prefix <= within[:, None], axis=1)
    valid = slot < total
    return jnp.where(valid, word * 32 + bit, 0), valid


@functools.partial(jax.jit, static_argnames=("max_points",))
def extract_surface(volume: TSDFVolume, max_points: int, weight_threshold: float | jax.Array = 1.0) -> Surface:
    """The zero crossings of the TSDF as points with normals, for segmentation and ICP.

    A point lies on each grid edge between two voxels of weight >= ``weight_threshold`` whose values have
    opposite signs and are both off the truncation edges (|f| < 0.99: a jump between +1 and -1 is where
    the band ends, not a surface), at the linear interpolation of the zero. Its normal is the normalised
    TSDF gradient (central differences at both voxels, interpolated alike), pointing to free space.
    When there are more crossings than ``max_points``, an evenly spread subset is kept.
    Returns ``Surface`` with points [P, 3] m, normals [P, 3], mask [P]; P = ``max_points``.
    """
    f, w = volume.tsdf, volume.weight  # read in their storage types; the gathered values cast to float32
    words = _crossing_words(f, w, weight_threshold, volume.storage)
    flat, mask = _select_bits(words.reshape(-1), max_points)
    X, Y, Z = volume.shape
    axis, rest = jnp.divmod(flat, X * Y * 32 * words.shape[-1])
    idx0 = jnp.stack(jnp.unravel_index(rest, (X, Y, 32 * words.shape[-1])), axis=-1).astype(jnp.int32)  # [P, 3]
    e = jax.nn.one_hot(axis, 3, dtype=jnp.int32)
    idx1 = jnp.minimum(idx0 + e, jnp.asarray([X - 1, Y - 1, Z - 1]))
    f0 = volume.storage.decode(f[idx0[:, 0], idx0[:, 1], idx0[:, 2]])
    f1 = volume.storage.decode(f[idx1[:, 0], idx1[:, 1], idx1[:, 2]])
    denom = f0 - f1
    safe = mask & (jnp.abs(denom) > 0)
    s = jnp.where(safe, f0 / jnp.where(safe, denom, 1.0), 0.0)[:, None]  # in [0, 1): fraction along the edge
    points = volume.origin + volume.voxel_size * (idx0.astype(jnp.float32) + s * e.astype(jnp.float32))

    grad = (1.0 - s) * _gradient_at(f, idx0, volume.storage) + s * _gradient_at(f, idx1, volume.storage)
    # Fallback where the central differences cancel: the difference along the crossing edge itself.
    fallback = e.astype(jnp.float32) * (f1 - f0)[:, None]
    grad = jnp.where(safe_norm(grad, keepdims=True) > 1e-6, grad, fallback)
    normals = normalize(grad, eps=0.0)
    m = mask[:, None]
    return Surface(points=jnp.where(m, points, 0.0), normals=jnp.where(m, normals, 0.0), mask=mask)
