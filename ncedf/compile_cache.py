"""The persistent compilation cache: a command run again loads its compiled programs instead of
compiling them again (most of a first run's start-up on a CPU).

The cache lives under ``$NCEDF_CACHE/xla`` (``~/.cache/ncedf/xla`` by default, beside the datasets),
in one folder per JAX version, device platform and CPU (its model and feature flags: compiled CPU
code may use instructions that another CPU lacks, and a home folder may be shared between
machines). JAX keys every program by its computation and compile options and writes each to its
own file. Concurrent processes share one folder: with a size limit (``MAX_BYTES``) JAX reads and
writes each entry under a file lock, so no process reads an entry another is still writing (without
one it warns that the entry is corrupt and compiles the program again), and drops the least recently
used entries past the limit. A folder named by JAX's own
``JAX_COMPILATION_CACHE_DIR`` is used instead (the test session shares one so). ``NCEDF_COMPILE_CACHE=0``
in the environment, or a command's ``--no-cache``, turns it off.
"""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path

import jax
from jax.experimental.compilation_cache.compilation_cache import reset_cache

from ncedf.data import cache_dir

#: The cache's size limit, bytes (a 7-link episode's programs take some 20 MB).
MAX_BYTES = 2 * 2**30
#: JAX's names of an entry's file and of the file of its last use (``jax._src.lru_cache``).
ENTRY_SUFFIX, USED_SUFFIX = "-cache", "-atime"
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
    """Point JAX's persistent compilation cache at ``folder``: every program, however quick to compile,
    entries read and written under JAX's file lock (``MAX_BYTES``). Entries that a cache without a limit
    wrote there get the file of their last use that JAX's eviction reads (else every later write fails)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for entry in folder.glob(f"*{ENTRY_SUFFIX}"):
        used = entry.with_name(entry.name.removesuffix(ENTRY_SUFFIX) + USED_SUFFIX)
        if not used.exists():
            used.write_bytes(entry.stat().st_mtime_ns.to_bytes(8, "little"))
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    # Else JAX also points XLA's GPU autotuning cache into the folder, which puts the folder's path into
    # every program's key (a copied cache would never hit).
    jax.config.update("jax_persistent_cache_enable_xla_caches", "none")


def enable_compile_cache(on: bool = True) -> Path | None:
    """Point JAX's persistent compilation cache at :func:`cache_folder` (:func:`use_folder`); nothing where ``on`` is False or the environment turns it off. JAX decides whether
    to use a cache at its first compilation; a process that compiled before is made to decide again.
    Returns the folder, or None."""
    if not (on and enabled()):
        return None
    folder = cache_folder()
    use_folder(folder)
    reset_cache()
    return folder
