"""PointNet classification of segments (paper Sec. 3.2, Eq. 1; Qi et al. 2017, the paper's [26]).

A segment is a padded cloud ``points: [P, 3]`` with ``mask: [P]``. The network sees it normalised (masked
mean subtracted, scaled into the unit sphere, as the paper's training clouds are) and aligns it with an
input T-Net (3x3); a shared MLP 64-64 follows, a feature T-Net (64x64, kept near orthogonal by
``orthogonality_loss``), a shared MLP 64-128-1024, a max-pool over the real points only, and a head
512-256-M with batch norm and dropout. Padded points never reach the pool nor the batch statistics, so
adding masked points changes nothing. Optionally (``ModelConfig.yaw_head``; the shipped default weights
have it) a second head 512-256-2M on the same pooled feature regresses, per class, (cos, sin) of the
class's yaw-symmetry order times the object's yaw: ``estimate_yaw``, the initial yaw of geometric
refinement.

Inference goes through a ``Classifier`` (weights + class list): ``classify`` gives probabilities for
``[N, P, 3]`` segments, ``top_k`` the candidates ICP chooses among. ``load_classifier()`` without a path
loads the weights shipped for the builtin object set.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import linen as nn
from flax import serialization, struct
from jax.experimental import pallas as pl

from jaxcls import io
from jaxcls.config import bounded, check_bounds
from jaxcls.math import safe_norm
from jaxcls.perception import kernels
from jaxcls.precision import MatmulPrecision

WEIGHTS_DIR = Path(__file__).parent / "weights"
# The weights shipped for the builtin object set, by name (``load_classifier("builtin_paper")``): ``builtin``
# from ``jaxcls train --config pointnet`` (complete, partial and in-scene clouds; calibrated), the default;
# ``builtin_paper`` from the paper's recipe (complete surfaces only; as trained, T = 1), for faithful rows.
SHIPPED_WEIGHTS = {"builtin": WEIGHTS_DIR / "pointnet_builtin.msgpack",
                   "builtin_paper": WEIGHTS_DIR / "pointnet_builtin_paper.msgpack"}
BUILTIN_WEIGHTS = SHIPPED_WEIGHTS["builtin"]


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """The network's hyper-parameters (the ``model:`` section of ``jaxcls/configs/pointnet.yaml``)."""

    num_points: int = bounded(1024, ge=1)  # points per cloud the network is trained on (segments are padded to this)
    dropout: float = bounded(0.3, ge=0.0, lt=1.0)  # before the last layer (PointNet's keep probability 0.7)
    bn_momentum: float = bounded(0.9, ge=0.0, lt=1.0)
    feature_transform_weight: float = bounded(0.001, ge=0.0)  # weight of ``orthogonality_loss``
    # A second head on the same trunk: per class, (cos, sin) of the class's yaw-symmetry order times the
    # object's yaw (geometric refinement's initial yaw; ``estimate_yaw``), trained with this loss weight.
    yaw_head: bool = False
    yaw_weight: float = bounded(1.0, ge=0.0)

    def __post_init__(self) -> None:
        check_bounds(self, "model.")


def normalise(points: jax.Array, mask: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Centre the real points on their mean and scale them into the unit sphere (the paper's recipe).

    points: [..., P, 3] m; mask: [..., P] bool. Non-finite points count as padding. Returns (points
    [..., P, 3] unitless, 0 where padded; mask [..., P] bool of the points kept).
    """
    mask = mask & jnp.all(jnp.isfinite(points), axis=-1)
    points = jnp.where(mask[..., None], points, 0.0)
    count = jnp.maximum(jnp.sum(mask, axis=-1, keepdims=True), 1)[..., None]
    centred = points - jnp.sum(points, axis=-2, keepdims=True) / count
    radius = jnp.max(jnp.where(mask, safe_norm(centred), 0.0), axis=-1)[..., None, None]
    return jnp.where(mask[..., None], centred / jnp.maximum(radius, 1e-9), 0.0), mask


def masked_max(features: jax.Array, mask: jax.Array) -> jax.Array:
    """[B, C] max over the real points of ``features: [B, P, C]`` (``mask: [B, P]``); 0 for an empty cloud."""
    pooled = jnp.max(jnp.where(mask[..., None], features, -jnp.inf), axis=-2)
    return jnp.where(jnp.any(mask, axis=-1)[..., None], pooled, 0.0)


_BN_EPSILON = 1e-5  # the shared MLPs' batch norm (flax's default), which ``_pooled_inference`` folds too


class PoolingKernel(enum.StrEnum):
    """How the network's pooled layers run at inference (``perception.classification_pooling``): ``xla``, the
    product [B, C, P] written out and its max over the points taken (the reference); ``pallas``, on a GPU one
    Pallas kernel a block of channels (``PoolBlocks``) keeping a running max over the points, the product never
    written (Triton), on any other platform the product then the max in XLA (``kernels.pallas_call``; ``xla``'s
    values where the weights are bfloat16, as the network's are in bfloat16); ``interpreted``, that kernel
    interpreted on every platform (slow: to check the kernel off a GPU). The kernel runs where the network computes
    in bfloat16 (``MatmulPrecision.bfloat16``) and the points, the layer's inputs and channels are powers of two
    (>= 16); elsewhere ``xla``."""

    xla = "xla"
    pallas = "pallas"
    interpreted = "interpreted"


class PoolBlocks(NamedTuple):
    """The Pallas pooling's blocks (``PoolingKernel.pallas``; a GPU's speed, not its values, depends on them):
    ``channels`` a program (its grid: segments / ``segments`` x C / channels), ``points`` a step of its loop over
    the points, ``warps`` a program (Triton), the max over the points taken each step (``accumulate=False``: a
    [channels] running max) or once at the end (``True``: a [points, channels] running elementwise max, no
    reduction across threads in the loop), and ``segments`` a program, one after another (the same channels' weights
    kept; the batch padded to a multiple). Powers of two; clipped to the layer's sizes."""

    channels: int = 128
    points: int = 64
    warps: int = 4
    accumulate: bool = False
    segments: int = 1


# The kernel's blocks in every network (a default argument: edit it here; benchmarks/pallas_kernels.py --pool-blocks
# compares others): the max over the points once at the end, 0.31 -> 0.24 ms alone on one H100 at 512 segments, the
# best of eight (BENCHMARKS.md, "The whole move on one H100: the Pallas kernels, their blocks, ...")
POOL_BLOCKS = PoolBlocks(accumulate=True)


def _max_product(x: jax.Array, mask: jax.Array, w: jax.Array) -> jax.Array:
    """[..., C] max over the real points p of ``x[..., p, :] @ w`` (-inf where none is real), the product
    [..., C, P] written out (``PoolingKernel.xla``). x: [..., P, Cin]; mask: [..., P] bool; w: [Cin, C]."""
    z = jnp.einsum("...pi,io->...op", x, w)  # [..., C, P]: the max runs along the minor axis
    return jnp.max(jnp.where(mask[..., None, :], z, -jnp.inf), axis=-1)


def _max_product_in_kernel(x: jax.Array, mask: jax.Array, w: jax.Array, interpreted: bool = False,
                           blocks: PoolBlocks = POOL_BLOCKS) -> jax.Array | None:
    """[..., C] max over the real points p of ``x[..., p, :] @ w`` (-inf where none is real) by one Pallas kernel
    (``blocks``), accumulated and compared in float32 and returned in ``x``'s type (off a GPU, ``_max_product``
    unless ``interpreted``); None where the kernel does not apply (``PoolingKernel``). x: [..., P, Cin] bfloat16;
    mask: [..., P] bool; w: [Cin, C]."""
    P, Cin = x.shape[-2:]
    C = w.shape[-1]

    def power_of_two(n: int, least: int = 16) -> bool:  # (Triton's blocks; its products need 16 or more a side)
        return kernels.power_of_two(n, least)

    if not (power_of_two(blocks.channels) and power_of_two(blocks.points) and power_of_two(blocks.warps, 1)
            and power_of_two(blocks.segments, 1)):
        raise ValueError(f"pointnet: the pooling kernel's blocks {blocks} need powers of two (16 or more a side)")
    if x.dtype != jnp.bfloat16 or not (power_of_two(P) and power_of_two(Cin) and power_of_two(C)):
        return None
    BC, BP, S = min(C, blocks.channels), min(P, blocks.points), blocks.segments
    group = (S,) if S > 1 else ()  # (a program's segments: one, the refs without that axis)

    def kernel(x_ref, mask_ref, w_ref, out_ref) -> None:  # (Pallas refs)
        block = w_ref[...]
        for s in range(S):  # (unrolled: S is small)
            at = (s,) if group else ()

            def step(t: jax.Array, best: jax.Array, at: tuple = at) -> jax.Array:
                points = pl.ds(t * BP, BP)
                z = jnp.dot(x_ref[(*at, points, slice(None))], block, preferred_element_type=jnp.float32)  # [BP, BC]
                z = jnp.where((mask_ref[(*at, points)] > 0)[:, None], z, -jnp.inf)
                return jnp.maximum(best, z if blocks.accumulate else jnp.max(z, axis=0))

            start = jnp.full((BP, BC) if blocks.accumulate else (BC,), -jnp.inf, jnp.float32)
            best = jax.lax.fori_loop(0, P // BP, step, start)
            out_ref[(*at, slice(None))] = (jnp.max(best, axis=0) if blocks.accumulate else best).astype(out_ref.dtype)

    def product(x: jax.Array, mask: jax.Array, w: jax.Array) -> jax.Array:  # (the kernel's arguments and result)
        return _max_product(x, mask > 0, w)

    def one(x: jax.Array, mask: jax.Array) -> jax.Array:  # x: [*group, P, Cin], mask: [*group, P] f32
        zeros = (0,) * len(group)
        return kernels.pallas_call(
            kernel, fallback=None if interpreted else product, num_warps=blocks.warps, grid=(C // BC,),
            in_specs=[pl.BlockSpec((*group, P, Cin), lambda j: (*zeros, 0, 0)),
                      pl.BlockSpec((*group, P), lambda j: (*zeros, 0)), pl.BlockSpec((Cin, BC), lambda j: (0, j))],
            out_specs=pl.BlockSpec((*group, BC), lambda j: (*zeros, j)),
            out_shape=jax.ShapeDtypeStruct((*group, C), x.dtype), name="pointnet_max_product")(
                x, mask, w.astype(x.dtype))

    batch = x.shape[:-2]
    x, mask = x.reshape(-1, P, Cin), mask.reshape(-1, P).astype(jnp.float32)
    count = x.shape[0]
    padding = -count % S  # (segments with no real point: -inf, dropped)
    x = jnp.pad(x, ((0, padding), (0, 0), (0, 0))).reshape(-1, *group, P, Cin)
    mask = jnp.pad(mask, ((0, padding), (0, 0))).reshape(-1, *group, P)
    return jax.vmap(one)(x, mask).reshape(-1, C)[:count].reshape(*batch, C)


class _SharedMLP(nn.Module):
    """Per-point Dense + batch norm (over real points) + ReLU, for each width; with ``pool``, then the max over
    the real points (``masked_max``): [B, C] instead of [B, P, C].

    Pooled at inference (``_pooled_inference``), the last layer's batch norm is folded into its Dense and the
    max taken before the per-channel shift and the ReLU (both monotone), on the product laid out channels x
    points: the [B, P, C] activations (C = 1024) are never normalised, rectified or transposed."""

    widths: Sequence[int]
    momentum: float
    pool: bool = False
    pooling: PoolingKernel = PoolingKernel.xla

    @nn.compact
    def __call__(self, x: jax.Array, mask: jax.Array, train: bool) -> jax.Array:
        last = len(self.widths) - 1
        for i, width in enumerate(self.widths):
            if i == last and self.pool and not train and not self.is_initializing():
                return _pooled_inference(x, mask, self.variables["params"][f"Dense_{i}"],
                                         self.variables["params"][f"BatchNorm_{i}"],
                                         self.variables["batch_stats"][f"BatchNorm_{i}"], self.pooling)
            x = nn.Dense(width)(x)
            x = nn.BatchNorm(use_running_average=not train, momentum=self.momentum, epsilon=_BN_EPSILON)(
                x, mask=mask[..., None])
            x = nn.relu(x)
        return masked_max(x, mask) if self.pool else x


def _pooled_inference(x: jax.Array, mask: jax.Array, dense: dict, norm: dict, stats: dict,
                      pooling: PoolingKernel = PoolingKernel.xla) -> jax.Array:
    """[B, C] ``masked_max(relu(batch_norm(x W + b)), mask)`` at inference (running statistics), computed as
    ``relu(max_p (x W') + c)``: W' = W a, c = a (b - mean) + beta, a = gamma / sqrt(var + eps) (the norm folded
    into the Dense; ReLU and the shift commute with the max). x: [B, P, Cin]; mask: [B, P]; dense: the Dense's
    {kernel [Cin, C], bias [C]}; norm: {scale, bias} [C]; stats: {mean, var} [C]. 0 for an empty cloud.
    ``pooling``: the max of the product as XLA's product and reduction, or one Pallas kernel (``PoolingKernel``)."""
    a = norm["scale"] * jax.lax.rsqrt(stats["var"] + _BN_EPSILON)
    shift = a * (dense["bias"] - stats["mean"]) + norm["bias"]
    kernel = dense["kernel"] * a
    pooling = PoolingKernel(pooling)
    pooled = None
    if pooling is not PoolingKernel.xla:
        pooled = _max_product_in_kernel(x, mask, kernel, pooling is PoolingKernel.interpreted)
    if pooled is None:
        pooled = _max_product(x, mask, kernel)
    return jnp.where(jnp.any(mask, axis=-1)[..., None], nn.relu(pooled + shift), 0.0)


class _Head(nn.Module):
    """Cloud-level Dense + batch norm + ReLU layers, optional dropout, and a final Dense."""

    widths: Sequence[int]
    out: int
    momentum: float
    dropout: float = 0.0
    out_kernel_init: Any = nn.initializers.lecun_normal()
    out_bias_init: Any = nn.initializers.zeros

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        for width in self.widths:
            x = nn.Dense(width)(x)
            x = nn.relu(nn.BatchNorm(use_running_average=not train, momentum=self.momentum)(x))
        if self.dropout:
            x = nn.Dropout(self.dropout, deterministic=not train)(x)
        return nn.Dense(self.out, kernel_init=self.out_kernel_init, bias_init=self.out_bias_init)(x)


def _identity_init(k: int):
    """Initialiser of a flattened k x k identity (a T-Net's starting transform)."""
    def init(key: jax.Array, shape: Sequence[int], dtype: Any = jnp.float32) -> jax.Array:
        return jnp.eye(k, dtype=dtype).reshape(shape)
    return init


class TNet(nn.Module):
    """A k x k transform predicted from the cloud (starts at the identity: zero kernel, identity bias)."""

    k: int
    momentum: float
    pooling: PoolingKernel = PoolingKernel.xla

    @nn.compact
    def __call__(self, x: jax.Array, mask: jax.Array, train: bool) -> jax.Array:
        h = _SharedMLP((64, 128, 1024), self.momentum, pool=True, pooling=self.pooling)(x, mask, train)
        out = _Head((512, 256), self.k * self.k, self.momentum, out_kernel_init=nn.initializers.zeros,
                    out_bias_init=_identity_init(self.k))
        return out(h, train).reshape(*x.shape[:-2], self.k, self.k)


class PointNet(nn.Module):
    """PointNet classification network. ``points: [B, P, 3]`` normalised (``normalise``), ``mask: [B, P]``.

    Returns (logits [B, M], feature transform [B, 64, 64], yaw [B, M, 2] or None): with ``yaw_head``, a
    second head on the pooled feature gives per class (cos, sin) of order x yaw (``estimate_yaw``).
    """

    num_classes: int
    dropout: float = 0.3
    momentum: float = 0.9
    yaw_head: bool = False
    pooling: PoolingKernel = PoolingKernel.xla  # the pooled layers at inference

    @nn.compact
    def __call__(self, points: jax.Array, mask: jax.Array, train: bool = False
                 ) -> tuple[jax.Array, jax.Array, jax.Array | None]:
        x = points @ TNet(3, self.momentum, self.pooling)(points, mask, train)
        x = _SharedMLP((64, 64), self.momentum)(x, mask, train)
        feature_transform = TNet(64, self.momentum, self.pooling)(x, mask, train)
        pooled = _SharedMLP((64, 128, 1024), self.momentum, pool=True, pooling=self.pooling)(
            x @ feature_transform, mask, train)
        logits = _Head((512, 256), self.num_classes, self.momentum, self.dropout)(pooled, train)
        yaw = None
        if self.yaw_head:
            yaw = _Head((512, 256), 2 * self.num_classes, self.momentum, name="yaw")(pooled, train)
            yaw = yaw.reshape(*yaw.shape[:-1], self.num_classes, 2)
        return logits, feature_transform, yaw


def orthogonality_loss(transform: jax.Array) -> jax.Array:
    """Mean over the batch of ||I - A A^T||_F^2 for ``transform: [B, k, k]`` (PointNet's regulariser)."""
    k = transform.shape[-1]
    gram = transform @ jnp.swapaxes(transform, -1, -2)
    return jnp.mean(jnp.sum((gram - jnp.eye(k)) ** 2, axis=(-2, -1)))


def make_model(num_classes: int, config: ModelConfig, pooling: PoolingKernel = PoolingKernel.xla) -> PointNet:
    """The network for ``num_classes`` outputs with ``config``'s dropout and batch-norm momentum; ``pooling``: how
    its pooled layers run at inference (``PoolingKernel``)."""
    return PointNet(num_classes=num_classes, dropout=config.dropout, momentum=config.bn_momentum,
                    yaw_head=config.yaw_head, pooling=PoolingKernel(pooling))


def init_variables(key: jax.Array, num_classes: int, config: ModelConfig) -> dict:
    """Fresh ``{"params", "batch_stats"}`` for ``num_classes`` outputs."""
    points = jnp.zeros((2, config.num_points, 3), jnp.float32)
    return dict(make_model(num_classes, config).init(key, points, jnp.ones((2, config.num_points), bool)))


@struct.dataclass
class Classifier:
    """Trained weights and what they mean.

    variables: flax ``{"params", "batch_stats"}``; classes: the class names, logits in this order;
    config: the network's hyper-parameters.
    """

    variables: dict
    classes: tuple[str, ...] = struct.field(pytree_node=False)
    config: ModelConfig = struct.field(pytree_node=False)
    # Temperature scaling (Guo et al. 2017): probabilities are softmax(logits / temperature); 1 = as trained.
    # Fitted on held-out training-instance scenes (``fit_temperature``), stored in the weights' .json.
    temperature: float = struct.field(pytree_node=False, default=1.0)
    # With a yaw head: each class's yaw-symmetry order (0 = turning it changes nothing: no yaw), the
    # multiple of the yaw the head regresses (``yaw_orders`` of the training instances).
    yaw_orders: tuple[int, ...] = struct.field(pytree_node=False, default=())

    def check_classes(self, classes: Sequence[str], source: str = "object set") -> None:
        """Raise ValueError unless ``classes`` is exactly the class list these weights were trained on."""
        if tuple(classes) != self.classes:
            raise ValueError(f"classifier: weights were trained on classes {list(self.classes)}, but the "
                             f"{source} has {list(classes)}; train on this set (jaxcls train) or load "
                             "matching weights")


def _forward(classifier: Classifier, points: jax.Array, mask: jax.Array, dtype: Any = jnp.float32,
             pooling: PoolingKernel = PoolingKernel.xla) -> tuple:
    """The network's outputs (logits, feature transform, yaw head or None; float32) on segments, shapes checked;
    ``dtype``: the type the network computes in (its weights and the normalised points cast to it); ``pooling``:
    its pooled layers' kernel (``PoolingKernel``)."""
    points_shape, mask_shape = tuple(np.shape(points)), tuple(np.shape(mask))
    if len(points_shape) != 3 or points_shape[-1] != 3:
        raise ValueError(f"classify: points must be [N, P, 3] (N segments of P points), got shape {points_shape}")
    if mask_shape != points_shape[:2]:
        raise ValueError(f"classify: mask must be [N, P] = {list(points_shape[:2])} like the points, got shape "
                         f"{mask_shape}")
    points, mask = normalise(jnp.asarray(points, jnp.float32), jnp.asarray(mask, bool))
    model = make_model(len(classifier.classes), classifier.config, pooling)
    variables = classifier.variables
    if jnp.dtype(dtype) != jnp.float32:
        points = points.astype(dtype)
        variables = jax.tree.map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, variables)
    outputs = model.apply(variables, points, mask, train=False)
    return jax.tree.map(lambda a: a.astype(jnp.float32), outputs)


@jax.jit
def logits(classifier: Classifier, points: jax.Array, mask: jax.Array) -> jax.Array:
    """[N, M] the network's uncalibrated class scores of segments (``classify``'s input; see there)."""
    return _forward(classifier, points, mask)[0]


@jax.jit
def estimate_yaw(classifier: Classifier, points: jax.Array, mask: jax.Array) -> jax.Array:
    """[N, M] rad: the yaw head's estimate of each segment's yaw about z if it were of class m, modulo
    2 pi / ``yaw_orders[m]`` (0 for a class whose order is 0: any yaw fits it). points: [N, P, 3] m, z up;
    mask: [N, P]. The yaw is that of the class's canonical model frame (``pose.initial_poses`` takes it)."""
    if not classifier.config.yaw_head:
        raise ValueError("estimate_yaw: these weights have no yaw head (train with model.yaw_head=true)")
    return _yaw_angles(classifier, _forward(classifier, points, mask)[2])


def _yaw_angles(classifier: Classifier, head: jax.Array) -> jax.Array:
    """[N, M] rad from the yaw head's [N, M, 2] (cos, sin) of order x yaw."""
    order = jnp.asarray(classifier.yaw_orders, jnp.float32)
    angle = jnp.arctan2(head[..., 1], head[..., 0]) / jnp.maximum(order, 1.0)
    return jnp.where(order > 0, angle, 0.0)


def yaw_orders(class_symmetries: Sequence[Sequence[int]]) -> tuple[int, ...]:
    """Per class, the yaw-symmetry order the yaw head regresses from its instances' orders
    (``ObjectModel.yaw_symmetry``: 0 continuous, k-fold, 1 none): the least common multiple of the
    finite ones (a turn by 2 pi / order maps every instance onto itself, so equal clouds never get
    different targets), 0 when every instance is continuous."""
    orders = []
    for symmetries in class_symmetries:
        finite = [int(k) for k in symmetries if k > 0]
        orders.append(int(np.lcm.reduce(finite)) if finite else 0)
    return tuple(orders)


def _calibrated(classifier: Classifier, scores: jax.Array, points: jax.Array, mask: jax.Array) -> jax.Array:
    """softmax(scores / temperature); the uniform 1/M for a segment with no real (finite, masked) point."""
    probs = jax.nn.softmax(scores / classifier.temperature, axis=-1)
    has_points = jnp.any(jnp.asarray(mask, bool) & jnp.all(jnp.isfinite(jnp.asarray(points)), axis=-1), axis=-1)
    return jnp.where(has_points[:, None], probs, 1.0 / len(classifier.classes))


@jax.jit
def classify(classifier: Classifier, points: jax.Array, mask: jax.Array) -> jax.Array:
    """Class probabilities of segments (paper Eq. 1's softmax), calibrated: softmax(logits / temperature).

    points: [N, P, 3] m (any frame with z up); mask: [N, P] bool; NaN or inf points count as padding.
    Returns probs [N, M]; a segment with no real point gets the uniform distribution 1/M. Other shapes
    are a ValueError naming them (checked while tracing: shapes are static). Deterministic: the same
    input gives the same output. ``logits`` gives the uncalibrated scores.
    """
    return _calibrated(classifier, logits(classifier, points, mask), points, mask)


@functools.partial(jax.jit, static_argnames=("precision", "pooling"))
def predict(classifier: Classifier, points: jax.Array, mask: jax.Array,
            precision: MatmulPrecision = MatmulPrecision.float32,
            pooling: PoolingKernel = PoolingKernel.xla) -> tuple[jax.Array, jax.Array]:
    """(probs [N, M] as ``classify``, yaw [N, M] rad as ``estimate_yaw``, zeros without a yaw head) from
    ONE forward pass: what a move needs for refinement with learned yaws. ``precision``: the network's
    products on an accelerator (``MatmulPrecision``; float32 and tf32 the same on a CPU; bfloat16 computes in
    bfloat16 everywhere); ``pooling``: the pooled layers' kernel (``PoolingKernel``: its Pallas kernel runs in
    bfloat16 only)."""
    precision = MatmulPrecision(precision)
    with precision.products():
        scores, _, head = _forward(classifier, points, mask, precision.dtype, PoolingKernel(pooling))
    yaw = _yaw_angles(classifier, head) if head is not None else jnp.zeros(scores.shape, jnp.float32)
    return _calibrated(classifier, scores, points, mask), yaw


def fit_temperature(scores: np.ndarray, labels: np.ndarray) -> float:
    """The temperature T that minimises the negative log-likelihood of ``labels: [K]`` under
    softmax(``scores: [K, M]`` / T) (temperature scaling: one scalar, argmax unchanged). T in [0.05, 20]."""
    from scipy.optimize import minimize_scalar
    from scipy.special import log_softmax

    scores, labels = np.asarray(scores, np.float64), np.asarray(labels)
    if scores.ndim != 2 or labels.shape != scores.shape[:1] or len(labels) == 0:
        raise ValueError(f"fit_temperature: need scores [K, M] and labels [K], got {scores.shape} and {labels.shape}")

    def nll(log_t: float) -> float:
        return -float(np.mean(log_softmax(scores / np.exp(log_t), axis=1)[np.arange(len(labels)), labels]))

    best = minimize_scalar(nll, bounds=(np.log(0.05), np.log(20.0)), method="bounded", options={"xatol": 1e-4})
    return float(np.exp(best.x))


@functools.partial(jax.jit, static_argnames=("k",))
def top_k(probs: jax.Array, k: int = 3) -> tuple[jax.Array, jax.Array]:
    """The k most probable classes of each segment (the candidates of Eq. 1).

    probs: [N, M]. Returns (scores [N, k] descending, class indices [N, k] i32); ties go to the lower index.
    """
    if not 1 <= k <= probs.shape[-1]:
        raise ValueError(f"top_k: need 1 <= k <= {probs.shape[-1]} classes, got k = {k}")
    return jax.lax.top_k(probs, k)


def save_classifier(path: str | Path, classifier: Classifier, metadata: dict | None = None,
                    dtype: Any = np.float16) -> Path:
    """Write weights as one msgpack file (stored in ``dtype``) and a JSON beside it (classes, config,
    ``metadata`` such as the accuracies measured)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stored = jax.tree.map(lambda a: np.asarray(a, dtype), classifier.variables)
    if not all(np.all(np.isfinite(a)) for a in jax.tree.leaves(stored)):
        raise ValueError(f"save_classifier: weights are not finite in {np.dtype(dtype).name}; save as float32")
    io.write_bytes(path, serialization.msgpack_serialize(serialization.to_state_dict(stored)))
    info = {"classes": list(classifier.classes), "model": dataclasses.asdict(classifier.config),
            "temperature": classifier.temperature, "yaw_orders": list(classifier.yaw_orders), **(metadata or {})}
    io.write_json(path.with_suffix(".json"), info, indent=2)
    return path


def load_classifier(path: str | Path | None = None, classes: Sequence[str] | None = None) -> Classifier:
    """Weights written by ``save_classifier``: a path, the name of a shipped set (``SHIPPED_WEIGHTS``), or
    None for the default shipped for the builtin object set.

    With ``classes``, raise ValueError unless the weights were trained on exactly that class list.
    """
    path = SHIPPED_WEIGHTS.get(str(path), path) if path is not None else BUILTIN_WEIGHTS
    path = Path(path)
    info_path = path.with_suffix(".json")
    for p in (path, info_path):
        if not p.is_file():
            raise FileNotFoundError(f"classifier: {p} not found (weights come as a .msgpack and a .json; "
                                    f"shipped names: {', '.join(SHIPPED_WEIGHTS)})")
    try:
        info = json.loads(info_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{info_path}: not valid JSON ({e}); it is written by save_classifier beside the "
                         ".msgpack weights") from None
    if not isinstance(info, dict):
        raise ValueError(f"{info_path}: expected a JSON object with 'classes' and 'model', got "
                         f"{type(info).__name__}")
    names = info.get("classes")
    if not isinstance(names, list) or not names or not all(isinstance(c, str) for c in names):
        raise ValueError(f"{info_path}: 'classes' must be a non-empty list of class names (strings), got "
                         f"{names!r}")
    names = tuple(names)
    if len(set(names)) != len(names):
        raise ValueError(f"{info_path}: 'classes' names a class twice: {list(names)}")
    model = info.get("model")
    if not isinstance(model, dict):
        raise ValueError(f"{info_path}: 'model' must be a JSON object of ModelConfig fields, got {model!r}")
    try:
        config = ModelConfig(**model)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{info_path}: 'model' is not a valid ModelConfig: {e}") from None
    # The variables' shapes, traced, not run: running the network once eagerly cost ~4 s of op-by-op compiles.
    template = jax.eval_shape(lambda: init_variables(jax.random.key(0), len(names), config))
    variables = io.read_weights(path, template, "classifier",
                                f"PointNet weights for the {len(names)} classes of {info_path.name}")
    temperature = info.get("temperature", 1.0)  # weights saved before calibration existed: as trained
    if isinstance(temperature, bool) or not isinstance(temperature, int | float) or not 0 < temperature < np.inf:
        raise ValueError(f"{info_path}: 'temperature' must be a positive number, got {temperature!r}")
    orders = info.get("yaw_orders", [])
    if config.yaw_head and (not isinstance(orders, list) or len(orders) != len(names)
                            or not all(isinstance(k, int) and k >= 0 for k in orders)):
        raise ValueError(f"{info_path}: 'yaw_orders' must list a yaw-symmetry order (int >= 0) per class for "
                         f"weights with a yaw head, got {orders!r}")
    # One transfer of every array (float32 on the host first): no conversion program per weight to compile or load.
    weights = jax.device_put(jax.tree.map(lambda a: np.asarray(a, np.float32), variables))
    classifier = Classifier(weights, names, config, float(temperature), tuple(orders) if config.yaw_head else ())
    if classes is not None:
        classifier.check_classes(classes)
    return classifier
