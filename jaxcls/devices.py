"""Where host-side bookkeeping runs: the process's CPU device, so that small computations (keys, believed poses,
quaternions, hand-eye logs) never wait in an accelerator's queue behind the batch it is running."""

from __future__ import annotations

import jax


def host_cpu() -> jax.Device:
    """The process's first CPU device; its first device where JAX has no CPU backend (``JAX_PLATFORMS=cuda``)."""
    try:
        return jax.local_devices(backend="cpu")[0]
    except RuntimeError:  # no CPU backend loaded
        return jax.local_devices()[0]


__all__ = ["host_cpu"]
