"""The persistent compilation cache: where it lives, the switch that turns it off, that a compiled
program lands in it and is read back by a fresh compilation, and that its entries are written under
JAX's file lock, also into a folder that a cache without the lock wrote."""

import warnings

import jax
import jax.numpy as jnp
import pytest

from jax.experimental.compilation_cache.compilation_cache import reset_cache

from ncedf.compile_cache import ENTRY_SUFFIX, ENV_SWITCH, USED_SUFFIX, cache_folder, enable_compile_cache, use_folder

OPTIONS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
           "jax_persistent_cache_enable_xla_caches", "jax_compilation_cache_max_size")


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


@pytest.mark.parametrize("value", ["0", "off", "False"])
def test_the_environment_or_the_flag_turns_it_off(tmp_path, monkeypatch, restored_config, value):
    monkeypatch.setenv("NCEDF_CACHE", str(tmp_path))
    before = jax.config.jax_compilation_cache_dir
    assert enable_compile_cache(on=False) is None
    monkeypatch.setenv(ENV_SWITCH, value)
    assert enable_compile_cache() is None
    assert jax.config.jax_compilation_cache_dir == before and not (tmp_path / "xla").exists()


def test_a_compiled_program_is_written_and_read_back(tmp_path, monkeypatch, restored_config):
    monkeypatch.setenv("NCEDF_CACHE", str(tmp_path))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.delenv(ENV_SWITCH, raising=False)
    folder = enable_compile_cache()
    assert folder == cache_folder() and jax.config.jax_compilation_cache_dir == str(folder)

    def program(x):
        return jnp.sin(x) * 3.25 + jnp.cumsum(x)  # a computation no other test compiles

    x = jnp.arange(7, dtype=jnp.float32)
    expected = jax.jit(program)(x)
    written = sorted(folder.glob(f"jit_program-*{ENTRY_SUFFIX}"))
    assert len(written) == 1, "the program was not written to the cache"
    stamp = written[0].stat().st_mtime_ns
    hits = []

    def listen(event, **_):
        hits.append(event)

    jax.monitoring.register_event_listener(listen)
    try:
        jax.clear_caches()  # a fresh compilation, as in a new process: served from the folder
        assert jnp.array_equal(jax.jit(program)(x), expected)
    finally:
        jax.monitoring.unregister_event_listener(listen)
    assert "/jax/compilation_cache/cache_hits" in hits
    assert sorted(folder.glob(f"jit_program-*{ENTRY_SUFFIX}")) == written and written[0].stat().st_mtime_ns == stamp


def test_entries_are_written_under_the_lock_also_beside_ones_a_cache_without_it_wrote(tmp_path, restored_config):
    """A folder holding an entry without the file of its last use (as a cache without a size limit writes
    them): a new program is written with its own, under JAX's lock file, without a warning (JAX's eviction
    reads every entry's last use before it writes: without the backfill the write fails), the old one kept."""
    old = tmp_path / f"jit_old-0123{ENTRY_SUFFIX}"
    old.write_bytes(b"an entry of an earlier run")
    use_folder(tmp_path)
    reset_cache()

    def program(x):
        return jnp.cos(x) * 1.75 - jnp.cumprod(x)  # a computation no other test compiles

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # JAX warns where it cannot write an entry
        jax.jit(program)(jnp.arange(5, dtype=jnp.float32))
    new = list(tmp_path.glob(f"jit_program-*{ENTRY_SUFFIX}"))
    assert len(new) == 1 and new[0].with_name(new[0].name.removesuffix(ENTRY_SUFFIX) + USED_SUFFIX).exists()
    assert old.exists() and (tmp_path / f"jit_old-0123{USED_SUFFIX}").exists() and (tmp_path / ".lockfile").exists()
