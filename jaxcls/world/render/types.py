"""What every depth backend returns and promises."""

from __future__ import annotations

import enum
from typing import Protocol

import jax
import numpy as np
from flax import struct

from jaxcls.geometry import Intrinsics


class Backend(enum.StrEnum):
    """Which renderer draws the depth frames: ``mujoco`` (MuJoCo's C ray casting on CPU threads), ``mjx``
    (MJX's pure-JAX ray casting), ``warp`` (MJX's batch renderer on a CUDA GPU). A config may say ``auto``:
    warp where a CUDA GPU and MuJoCo Warp are present, else mujoco (``render.resolve_backend``)."""

    auto = "auto"
    mujoco = "mujoco"
    mjx = "mjx"
    warp = "warp"


BACKENDS: tuple[Backend, ...] = (Backend.mujoco, Backend.mjx, Backend.warp)  # the renderers (not ``auto``)

# Sentinels of the return contract (docs/ARCHITECTURE.md): no return has depth 0; the table and misses have id -1.
NO_DEPTH = 0.0
NO_OBJECT = -1


@struct.dataclass
class DepthFrames:
    """A batch of rendered depth maps and the object each pixel sees.

    depth:     [B, H, W] f32 z-depth in metres (along the optical axis), 0 = no return, never NaN.
    object_id: [B, H, W] i32 index i of the body ``object_i`` hit, -1 = table or nothing.

    NumPy arrays from the ``mujoco`` backend, JAX arrays from ``mjx`` and ``warp``.
    """

    depth: np.ndarray | jax.Array
    object_id: np.ndarray | jax.Array


class Renderer(Protocol):
    """A depth camera over one fixed scene; ``render`` takes OpenCV camera-to-world poses."""

    intrinsics: Intrinsics
    backend: Backend

    def render(self, T_wc: np.ndarray) -> DepthFrames:
        """T_wc: [B, 4, 4] or [4, 4] camera-to-world poses, metres. Returns [B, H, W] frames."""
        ...
