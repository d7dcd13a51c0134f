"""XLA's code generation where the CPU is the only device: LLVM at optimisation level 1.

Most of a first run's start-up on a CPU is XLA compiling (``ncedf.compile_cache``),
and most of that is LLVM optimising the generated loops. XLA has fused and
vectorised them before LLVM sees them, so level 1 (instead of XLA's default)
compiles them faster and runs them as fast (``bench/startup.py``,
``bench/closed_loop.py --timing``; the figures are in ``docs/experiments.md``).

It is set in ``XLA_FLAGS`` when ``ncedf`` is imported, before JAX starts its
backend, and only where JAX can run on nothing but the CPU (no device plugin
installed, ``JAX_PLATFORMS`` unset or ``cpu``): other devices' compilers are left
as they are. A level the user names in ``XLA_FLAGS`` is kept.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os

#: The XLA flag and the level set.
FLAG = "--xla_backend_optimization_level"
LEVEL = 1


def device_plugins() -> bool:
    """Whether a JAX device plugin (CUDA, ROCm, TPU, ...) is installed."""
    if importlib.metadata.entry_points(group="jax_plugins"):
        return True
    try:
        return importlib.util.find_spec("jax_plugins") is not None
    except (ImportError, ValueError):
        return False


def cpu_flags(environ=os.environ, plugins=None) -> None:
    """Add ``FLAG=LEVEL`` to ``environ["XLA_FLAGS"]`` where the CPU is the only device and the
    flag is not there yet (``plugins``: whether device plugins are installed; None: look)."""
    if FLAG in environ.get("XLA_FLAGS", "") or environ.get("JAX_PLATFORMS", "cpu") not in ("", "cpu"):
        return
    if device_plugins() if plugins is None else plugins:
        return
    environ["XLA_FLAGS"] = f"{environ.get('XLA_FLAGS', '')} {FLAG}={LEVEL}".strip()
