"""The precision of every matrix product in the package's JAX code: full float32.

At its default precision XLA on NVIDIA GPUs since Ampere rounds the inputs of a
float32 matrix product to TF32 (10 mantissa bits), a relative error near 1e-3:
on a distance of 2 m, 2 mm, and two batchings of the same product round
differently (the broad phase and brute force then disagree; ``docs/experiments.md``
has the measurement). CPUs compute it in float32 either way.
"""

from __future__ import annotations

import jax

#: ``precision`` of every ``einsum``, ``dot`` and Dense layer.
MATMUL = jax.lax.Precision.HIGHEST
