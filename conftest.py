"""Settings of the test session (here, not in tests/: a conftest there would put tests/ first
on the import path, where tests/recorder would hide the recorder package).

XLA builds the tests' programs at backend optimisation level 0 (no LLVM optimisation of the
generated code): on a 2-core machine most of the suite's time is compilation, not execution
(the suite: 464 s instead of 576 s). The programs hold the same operations; the commands and
benchmarks keep XLA's default level. A level already in ``XLA_FLAGS`` is kept, and the
commands the tests start as subprocesses inherit the setting.
"""

import os

OPTIMISATION = "--xla_backend_optimization_level"

if OPTIMISATION not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {OPTIMISATION}=0".strip()
