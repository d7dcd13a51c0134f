"""The persistent compilation cache: where it lives, the switch that turns it off (JAX's own folder
too), and that a compiled program lands in it and is read back by a fresh compilation."""

import jax
import jax.numpy as jnp
import pytest

from jax.experimental.compilation_cache.compilation_cache import reset_cache

from ncedf.compile_cache import ENV_SWITCH, cache_folder, enable_compile_cache, use_folder

OPTIONS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
           "jax_persistent_cache_enable_xla_caches", "jax_enable_compilation_cache")


@pytest.fixture
def restored_config():
    before = {name: getattr(jax.config, name) for name in OPTIONS}
    yield
    for name, value in before.items():
        jax.config.update(name, value)
    reset_cache()  # the worker's later compilations decide again, without the folder


def test_the_folder_is_under_the_projects_cache_and_names_jax_and_the_platform(tmp_path, monkeypatch):
    monkeypatch.setenv("NCEDF_CACHE", str(tmp_path))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    folder = cache_folder()
    assert folder.parent == tmp_path / "xla"
    assert folder.name.startswith(f"jax{jax.__version__}-{jax.default_backend()}-")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "shared"))  # JAX's own variable wins
    assert cache_folder() == tmp_path / "shared"


@pytest.mark.parametrize("value", [None, "0", "off", "False"])
def test_the_environment_or_the_flag_turns_it_off(tmp_path, monkeypatch, restored_config, value):
    """``on=False`` (value None) or the environment switch, each alone, turns off a cache that was on."""
    monkeypatch.setenv("NCEDF_CACHE", str(tmp_path))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.delenv(ENV_SWITCH, raising=False)
    use_folder(tmp_path / "jax")  # on, in a folder of its own
    if value is None:
        assert enable_compile_cache(on=False) is None
    else:
        monkeypatch.setenv(ENV_SWITCH, value)
        assert enable_compile_cache() is None
    assert not (tmp_path / "xla").exists()
    jax.jit(lambda x: jnp.tan(x) * len(str(value)) - 0.375)(jnp.arange(3.0))  # a program no other test compiles
    assert not list((tmp_path / "jax").glob("*"))


def test_a_compiled_program_is_written_and_read_back(tmp_path, monkeypatch, restored_config):
    monkeypatch.setenv("NCEDF_CACHE", str(tmp_path))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.delenv(ENV_SWITCH, raising=False)
    folder = enable_compile_cache()
    assert folder == cache_folder() and jax.config.jax_compilation_cache_dir == str(folder)

    def fresh():
        """A new function object each call: JAX traces it afresh, as a new process would."""
        def program(x):
            return jnp.sin(x) * 3.25 + jnp.cumsum(x)  # a computation no other test compiles
        return program

    x = jnp.arange(7, dtype=jnp.float32)
    expected = jax.jit(fresh())(x)
    written = sorted(folder.glob("jit_program-*"))
    assert len(written) == 1, "the program was not written to the cache"
    stamp = written[0].stat().st_mtime_ns
    hits = []

    def listen(event, **_):
        hits.append(event)

    jax.monitoring.register_event_listener(listen)
    try:
        assert jnp.array_equal(jax.jit(fresh())(x), expected)  # served from the folder
    finally:
        jax.monitoring.unregister_event_listener(listen)
    assert "/jax/compilation_cache/cache_hits" in hits
    assert sorted(folder.glob("jit_program-*")) == written and written[0].stat().st_mtime_ns == stamp
