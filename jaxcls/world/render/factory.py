"""Choosing and building a depth backend."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax

from jaxcls.geometry import Intrinsics
from jaxcls.world.render.types import BACKENDS, Backend, Renderer

if TYPE_CHECKING:
    import mujoco


def _has_cuda() -> bool:
    try:
        return bool(jax.devices("cuda"))
    except RuntimeError:
        return False


def default_backend() -> str:
    """``"warp"`` where a CUDA GPU and warp-lang are present (MJX's batch renderer), else ``"mujoco"``.

    MJX (and warp-lang, which prints when it is missing) is imported only where a CUDA GPU is present.
    """
    if not _has_cuda():
        return "mujoco"
    from jaxcls.world.render.warp import warp_unavailable_reason

    return "warp" if warp_unavailable_reason() is None else "mujoco"


def resolve_backend(name: str) -> Backend:
    """A config's backend name: ``"auto"`` becomes ``default_backend()``; others are checked."""
    if name == "auto":
        return default_backend()
    if name not in BACKENDS:
        raise ValueError(f"unknown render backend {name!r}; choose 'auto' or one of {BACKENDS}")
    return name


def make_renderer(model: mujoco.MjModel, intrinsics: Intrinsics, backend: Backend = "mujoco",
                  **options: object) -> Renderer:
    """A depth renderer of the static scene ``model`` (the scene contract, ``render.contract``).

    backend: ``"mujoco"`` (C ray casting on CPU threads; options ``workers: int | None``, default all
    cores, and ``cull: bool = True``, casting in C only near objects), ``"mjx"`` (pure-JAX ray casting;
    option ``chunk: int``, rays per vmapped chunk) or ``"warp"`` (MJX's batch renderer on a CUDA GPU;
    option ``kinematics: "forward" | "static"``, see ``render.warp``).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown render backend {backend!r}; choose one of {BACKENDS}")
    if backend == "mujoco":
        from jaxcls.world.render.native import NativeRenderer

        return NativeRenderer(model, intrinsics, **options)
    if backend == "mjx":
        from jaxcls.world.render.mjx_ray import MJXRenderer

        return MJXRenderer(model, intrinsics, **options)
    from jaxcls.world.render.warp import WarpRenderer

    return WarpRenderer(model, intrinsics, **options)
