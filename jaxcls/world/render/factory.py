"""Choosing and building a depth backend."""

from __future__ import annotations

import importlib.util
from typing import TYPE_CHECKING, Literal

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

    Nothing is imported to tell: MJX and MuJoCo Warp take ~4 s to import on a GPU machine, which a process then
    spends where it first renders (e.g. on Table 1's frames thread, beside its classifiers' loads), not where it
    reads its config. A warp-lang that is present but fails to import is reported by the renderer
    (``WarpRenderer``: ``render.warp.warp_unavailable_reason``), not passed over for the CPU caster.
    """
    if not _has_cuda() or importlib.util.find_spec("warp") is None:
        return Backend.mujoco
    return Backend.warp


def loads_beside_renders(kinematics: Literal["forward", "static"]) -> bool:
    """Whether another thread may load a program onto the GPU while a ``WarpRenderer`` of ``kinematics``
    renders (known without importing MJX). Not under Warp's own (staged) CUDA graph capture, ``forward``: a load
    beside it broke the capture ("Warp CUDA error 901: operation failed due to a previous error during capture",
    or a crash, within seconds on an H200). ``static`` runs in JAX's graph mode, where JAX captures: three 30 s
    loops of ~110 scene-bank renders beside a thread compiling and running ~110 programs all finished (one H100,
    2026-11-27)."""
    return kinematics == "static"


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
