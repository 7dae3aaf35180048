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


def default_backend() -> Backend:
    """``"warp"`` where a CUDA GPU and warp-lang are present (MJX's batch renderer), else ``"mujoco"``.

    MJX (and warp-lang, which prints when it is missing) is imported only where a CUDA GPU is present.
    """
    if not _has_cuda():
        return Backend.mujoco
    from jaxcls.world.render.warp import warp_unavailable_reason

    return Backend.warp if warp_unavailable_reason() is None else Backend.mujoco


def resolve_backend(name: Backend | str) -> Backend:
    """A config's backend: ``auto`` becomes ``default_backend()``; others are checked."""
    if name not in set(Backend):
        raise ValueError(f"unknown render backend {name!r}; choose one of {[str(b) for b in Backend]}")
    return default_backend() if Backend(name) is Backend.auto else Backend(name)


def _renderer_class(backend: Backend) -> type[Renderer]:
    """The renderer of ``backend``, imported only when asked for (MJX and Warp load slowly)."""
    if backend is Backend.mujoco:
        from jaxcls.world.render.native import NativeRenderer

        return NativeRenderer
    if backend is Backend.mjx:
        from jaxcls.world.render.mjx_ray import MJXRenderer

        return MJXRenderer
    from jaxcls.world.render.warp import WarpRenderer

    return WarpRenderer


def make_renderer(model: mujoco.MjModel, intrinsics: Intrinsics, backend: Backend | str = Backend.mujoco,
                  **options: object) -> Renderer:
    """A depth renderer of the static scene ``model`` (the scene contract, ``render.contract``).

    backend: ``"mujoco"`` (C ray casting on CPU threads; options ``workers: int | None``, default all
    cores, and ``cull: bool = True``, casting in C only near objects), ``"mjx"`` (pure-JAX ray casting;
    option ``chunk: int``, rays per vmapped chunk) or ``"warp"`` (MJX's batch renderer on a CUDA GPU;
    option ``kinematics: "forward" | "static"``, see ``render.warp``).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown render backend {backend!r}; choose one of {[str(b) for b in BACKENDS]}")
    return _renderer_class(Backend(backend))(model, intrinsics, **options)
