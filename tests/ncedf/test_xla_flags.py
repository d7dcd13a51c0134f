"""Where ``ncedf`` sets XLA's backend optimisation level."""

import os
import subprocess
import sys

from ncedf.xla_flags import FLAG, LEVEL, cpu_flags, device_plugins


def test_a_cpu_only_install_gets_the_level_beside_the_users_flags():
    env = {"XLA_FLAGS": "--xla_dump_to=/tmp/x"}
    cpu_flags(env, plugins=False)
    assert env["XLA_FLAGS"] == f"--xla_dump_to=/tmp/x {FLAG}={LEVEL}"
    cpu_flags(env, plugins=False)  # once only
    assert env["XLA_FLAGS"].count(FLAG) == 1
    fresh = {}
    cpu_flags(fresh, plugins=False)
    assert fresh == {"XLA_FLAGS": f"{FLAG}={LEVEL}"}


def test_other_devices_and_the_users_own_level_are_left_alone():
    for env, plugins in (({}, True), ({"JAX_PLATFORMS": "cuda"}, False), ({"XLA_FLAGS": f"{FLAG}=3"}, False)):
        before = dict(env)
        cpu_flags(env, plugins=plugins)
        assert env == before


def test_importing_ncedf_sets_it_in_a_process_that_did_not():
    """A fresh interpreter without the test session's XLA settings: importing ``ncedf`` sets the
    level where no device plugin is installed, and leaves the flags alone where one is."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_PLATFORMS")}
    code = "import os, ncedf; print(os.environ.get('XLA_FLAGS', ''))"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    expected = "" if device_plugins() else f"{FLAG}={LEVEL}"
    assert done.stdout.strip() == expected
