"""The persistent compilation cache: a command run again loads its compiled programs instead of
compiling them again (most of a first run's start-up on a CPU).

The cache lives under ``$NCEDF_CACHE/xla`` (``~/.cache/ncedf/xla`` by default, beside the datasets),
in one folder per JAX version, device platform and CPU (its model and feature flags: compiled CPU
code may use instructions that another CPU lacks, and a home folder may be shared between
machines). JAX keys every program by its computation and compile options and writes each to its
own file, so concurrent processes share one folder (a process that reads an entry while another
still writes it warns that it cannot read it and compiles the program again). A folder named by JAX's own
``JAX_COMPILATION_CACHE_DIR`` is used instead (the test session shares one so). ``NCEDF_COMPILE_CACHE=0``
in the environment, or a command's ``--no-cache``, turns it off, JAX's folder too.

Batches of varying size are padded to a few sizes (:func:`bucket`), so that they share compiled programs.
"""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path

import jax
from jax.experimental.compilation_cache.compilation_cache import reset_cache

from ncedf.data import cache_dir

#: The environment variable that turns the cache off when set to 0 (or "off", "false", "no").
ENV_SWITCH = "NCEDF_COMPILE_CACHE"
_OFF = ("0", "off", "false", "no")


def cpu_identity() -> str:
    """The CPU's model and feature flags (Linux: the first processor of /proc/cpuinfo), else the
    platform's processor and machine names."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    wanted = [line for line in lines if line.split(":")[0].strip() in ("model name", "flags", "Features")]
    return "\n".join(dict.fromkeys(wanted)) or f"{platform.processor()} {platform.machine()}"


def cache_folder() -> Path:
    """This machine's folder of the cache: ``$JAX_COMPILATION_CACHE_DIR`` where set, else
    ``$NCEDF_CACHE/xla/<jax version>-<platform>-<cpu hash>``."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    cpu = hashlib.sha256(cpu_identity().encode()).hexdigest()[:12]
    return cache_dir() / "xla" / f"jax{jax.__version__}-{jax.default_backend()}-{cpu}"


def enabled() -> bool:
    """Whether the environment leaves the cache on."""
    return os.environ.get(ENV_SWITCH, "1").strip().lower() not in _OFF


def add_cache_option(parser) -> None:
    """A command's ``--no-cache`` flag (``args.no_cache``), for ``enable_compile_cache(not args.no_cache)``."""
    parser.add_argument("--no-cache", action="store_true",
                        help="compile afresh, without the persistent compilation cache (ncedf.compile_cache)")


def use_folder(folder) -> None:
    """Point JAX's persistent compilation cache at ``folder``: every program, however quick to compile.
    JAX decides whether to use a cache at its first compilation; a process that compiled before is
    made to decide again."""
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # Else JAX also points XLA's GPU autotuning cache into the folder, which puts the folder's path into
    # every program's key (a copied cache would never hit).
    jax.config.update("jax_persistent_cache_enable_xla_caches", "none")
    reset_cache()


def enable_compile_cache(on: bool = True) -> Path | None:
    """Point JAX's persistent compilation cache at :func:`cache_folder` (:func:`use_folder`), or turn it
    off (JAX decides again) where ``on`` is False or the environment turns it off. Returns the folder,
    or None."""
    if not (on and enabled()):
        jax.config.update("jax_enable_compilation_cache", False)
        reset_cache()
        return None
    folder = cache_folder()
    use_folder(folder)
    return folder


def bucket(n: int, smallest: int = 256) -> int:
    """The padded size of a batch of n (a power of two >= smallest): one compilation per bucket, not
    per batch size, for at most twice the work."""
    return max(smallest, 1 << max(n - 1, 0).bit_length())
