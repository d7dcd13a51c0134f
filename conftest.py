"""Settings of the test session (here, not in tests/: a conftest there would put tests/ first
on the import path, where tests/recorder would hide the recorder package).

XLA builds the tests' programs at backend optimisation level 0 (no LLVM optimisation of the
generated code): on a 2-core machine most of the suite's time is compilation, not execution
(the suite: 464 s instead of 576 s). The programs hold the same operations; the commands and
benchmarks keep XLA's default level. A level already in ``XLA_FLAGS`` is kept, and the
commands the tests start as subprocesses inherit the setting.

The session's processes (the two workers and the commands they start) also share a persistent
JAX compilation cache in a temporary folder, removed at the end: a program one of them compiled
is loaded, not compiled again, by the others (the cluttered command's tiny run: 43 s, 20 s with
the cache warm). A loaded program is the compiled one, so results are unchanged. A cache folder
already in ``JAX_COMPILATION_CACHE_DIR`` is used as it is and kept.
"""

import atexit
import os
import shutil
import tempfile

OPTIMISATION = "--xla_backend_optimization_level"

if OPTIMISATION not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {OPTIMISATION}=0".strip()

if "JAX_COMPILATION_CACHE_DIR" not in os.environ:  # the first process of the session: the workers inherit it
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="ncedf-test-jax-cache-")
    atexit.register(shutil.rmtree, os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)
    # Every program, however quick to compile; and no XLA autotuning caches, whose folder would enter the keys.
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    os.environ["JAX_PERSISTENT_CACHE_ENABLE_XLA_CACHES"] = "none"
