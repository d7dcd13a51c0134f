"""Where ``ncedf`` sets XLA's backend optimisation level."""

from ncedf.xla_flags import FLAG, LEVEL, cpu_flags


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


def test_importing_ncedf_set_it_where_jax_runs_on_the_cpu():
    import os

    import jax

    if jax.default_backend() == "cpu":
        assert FLAG in os.environ.get("XLA_FLAGS", "")
