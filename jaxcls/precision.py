"""Float32 matrix products at full float32 precision on accelerators (no TF32 or bfloat16 passes).

On a GPU, XLA runs float32 ``dot``/``einsum``/``@`` at its default precision through the tensor cores
(TF32: a 10-bit mantissa, ~5e-4 relative). Camera poses applied to points a metre away then move them by
~0.5 mm, and the TSDF's projection and PointNet's features drift from the CPU's. The geometry's own
products pass ``precision=HIGHEST`` where they were found to matter; ``full_float32_matmuls`` makes it the
process-wide default, so that TF32 is not one of the differences between a GPU's and a CPU's episodes.
Others remain (the kernels' summation orders): with sensor noise, a GPU and a CPU episode still part at
near-ties of ICP or the view utility now and then (RESULTS.md, "CPU against GPU").

It changes a process-wide setting, so nothing calls it on import: the episode commands (``jaxcls run`` /
``jaxcls demo``), ``experiments/table1.py`` and the episode benchmarks call it at start-up. Training
(``jaxcls train``) keeps the default: it gains from TF32 and needs no bit-level agreement.
"""

from __future__ import annotations

import contextlib
import enum

import jax
import jax.numpy as jnp


def full_float32_matmuls() -> bool:
    """Set ``jax_default_matmul_precision`` to "highest" where the default backend is an accelerator; on the
    CPU, float32 products are full precision already and nothing changes. True if it was set."""
    if jax.default_backend() == "cpu":
        return False
    jax.config.update("jax_default_matmul_precision", "highest")
    return True


def fused_products(fused: bool | None = None) -> bool:
    """Whether a small float32 product (``math.row_dots``' 3 terms, ``geometry.rotate`` among them, and
    ``math.normal_equations``' K x K) runs as
    elementwise products and sums (True), which XLA fuses into the operations around them, or as a matrix product
    at HIGHEST precision (False): ``fused`` where given, else True on an accelerator (a product of 3 terms is a
    slow kernel of its own there) and False on the CPU (the elementwise form's rounding depends on vmap there,
    and a vmapped move must equal the sequential one)."""
    return jax.default_backend() != "cpu" if fused is None else fused


class MatmulPrecision(enum.StrEnum):
    """The float32 products of one stage on an accelerator (a CPU runs every one at full float32):
    ``float32``, full precision (the reference; the process's default once ``full_float32_matmuls`` ran);
    ``tf32``, XLA's default precision, which on an H100 or H200 runs float32 products on the tensor cores as
    TF32 (10-bit mantissa, ~5e-4 relative); ``bfloat16``, the network's weights, activations and products in
    bfloat16 (8-bit mantissa, ~4e-3 relative; on a CPU too), its outputs back in float32: half the activations'
    memory traffic and the tensor cores' bfloat16 rate. Only stages whose outputs are scores, not camera poses,
    take them (``perception.classification_precision``: PointNet)."""

    float32 = "float32"
    tf32 = "tf32"
    bfloat16 = "bfloat16"

    def products(self) -> contextlib.AbstractContextManager:
        """A context in which the products traced take this precision (``jax.default_matmul_precision``)."""
        return jax.default_matmul_precision("highest" if self is MatmulPrecision.float32 else "default")

    @property
    def dtype(self) -> jnp.dtype:
        """The type the stage computes in: bfloat16 for ``bfloat16``, else float32."""
        return jnp.dtype(jnp.bfloat16 if self is MatmulPrecision.bfloat16 else jnp.float32)


__all__ = ["MatmulPrecision", "full_float32_matmuls", "fused_products"]
