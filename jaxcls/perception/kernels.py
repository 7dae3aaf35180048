"""The move's Pallas kernels, run where they are lowered: compiled by Triton on an NVIDIA GPU; on any other
platform the same arithmetic in XLA (the caller's ``fallback``), or, to check a kernel off a GPU, the kernel
interpreted (slow: ~40x XLA's fusion on a CPU).

``pallas_call`` is the one place that builds them (``tsdf.FusionKernel``, ``pointnet.PoolingKernel``): the
platform is chosen where the program is lowered (``lax.platform_dependent``), not by the process's default
backend, so a kernel inside a program placed on the host CPU of a GPU machine takes the fallback there. Triton is
named explicitly (``compiler_params``): JAX 0.10 otherwise picks Mosaic GPU, which does not batch a kernel under
``vmap``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
from jax.experimental import pallas as pl


def power_of_two(n: int, least: int = 1) -> bool:
    """Whether ``n`` is a power of two of at least ``least`` (Triton's block sizes)."""
    return n >= least and n & (n - 1) == 0


def pallas_call(kernel: Callable[..., None], *, fallback: Callable[..., Any] | None, num_warps: int = 4,
                **kwargs: Any) -> Callable[..., Any]:
    """``pl.pallas_call(kernel, **kwargs)``, compiled by Triton (``num_warps`` warps a program) where the program
    is lowered for a CUDA GPU, and ``fallback`` (the same arguments and results: the arithmetic in XLA) where it
    is lowered for another platform; with ``fallback=None``, the kernel interpreted on every platform. Its
    batching under ``vmap`` is Pallas' (a grid axis)."""
    if fallback is None:
        return pl.pallas_call(kernel, interpret=True, **kwargs)
    from jax.experimental.pallas import triton as plgpu  # (here: the package imports whatever Pallas' backends)

    compiled = pl.pallas_call(kernel, compiler_params=plgpu.CompilerParams(num_warps=num_warps), **kwargs)

    def call(*args: jax.Array) -> Any:
        return jax.lax.platform_dependent(*args, cuda=compiled, default=fallback)

    return call
