"""Settings of the test session (here, not in tests/: a conftest there would put tests/ first
on the import path, where tests/recorder would hide the recorder package).

XLA builds the tests' programs at backend optimisation level 0 (no LLVM optimisation of the
generated code) and with its older CPU fusion emitters (not the MLIR ones): on a 2-core machine
most of the suite's time is compilation, not execution, and both compile the same operations
faster (two programs may then round 1 ulp apart where they fuse apart; the measurements are in
``docs/experiments.md``).
The commands and benchmarks keep XLA's defaults. A setting already in ``XLA_FLAGS`` is kept,
and the commands the tests start as subprocesses inherit these.

The session's processes (the two workers and the commands they start) also share a persistent
JAX compilation cache in a temporary folder, removed at the end: a program one of them compiled
is loaded, not compiled again, by the others. A loaded program is the compiled one, so results
are unchanged. A cache folder
already in ``JAX_COMPILATION_CACHE_DIR`` is used as it is and kept.
"""

import atexit
import os
import shutil
import tempfile

#: XLA flags of the test session and their values there.
QUICK_COMPILE = {"--xla_backend_optimization_level": "0", "--xla_cpu_use_fusion_emitters": "false"}

for flag, value in QUICK_COMPILE.items():
    if flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}={value}".strip()

if "JAX_COMPILATION_CACHE_DIR" not in os.environ:  # the first process of the session: the workers inherit it
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="ncedf-test-jax-cache-")
    atexit.register(shutil.rmtree, os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)
    # Every program, however quick to compile; and no XLA autotuning caches, whose folder would enter the keys.
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    os.environ["JAX_PERSISTENT_CACHE_ENABLE_XLA_CACHES"] = "none"
