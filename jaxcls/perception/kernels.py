"""The move's Pallas kernels, run where they are lowered: compiled by Triton on an NVIDIA GPU, interpreted on any
other platform (a CPU: slow, for tests and small runs).

``pallas_call`` is the one place that builds them (``tsdf.FusionKernel.pallas``, ``pointnet.PoolingKernel.pallas``):
the platform is chosen where the program is lowered (``lax.platform_dependent``), not by the process's default
backend, so a kernel inside a program placed on the host CPU of a GPU machine is interpreted there. Triton is named
explicitly (``compiler_params``): JAX 0.10 otherwise picks Mosaic GPU, which does not batch a kernel under ``vmap``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
from jax.experimental import pallas as pl


def pallas_call(kernel: Callable[..., None], *, num_warps: int = 4, **kwargs: Any) -> Callable[..., Any]:
    """``pl.pallas_call(kernel, **kwargs)``, compiled by Triton (``num_warps`` warps a program) where the program
    is lowered for a CUDA GPU and interpreted elsewhere; its batching under ``vmap`` is Pallas' (a grid axis)."""
    from jax.experimental.pallas import triton as plgpu  # (here: the package imports whatever Pallas' backends)

    compiled = pl.pallas_call(kernel, compiler_params=plgpu.CompilerParams(num_warps=num_warps), **kwargs)
    interpreted = pl.pallas_call(kernel, interpret=True, **kwargs)

    def call(*args: jax.Array) -> Any:
        return jax.lax.platform_dependent(*args, cuda=compiled, default=interpreted)

    return call
