"""What every depth backend returns and promises."""

from __future__ import annotations

from typing import Literal, Protocol

import jax
import numpy as np
from flax import struct

from jaxcls.geometry import Intrinsics

Backend = Literal["mujoco", "mjx", "warp"]
BACKENDS: tuple[Backend, ...] = ("mujoco", "mjx", "warp")
BackendChoice = Literal["auto", "mujoco", "mjx", "warp"]  # a config's choice: "auto" picks warp on a GPU

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
