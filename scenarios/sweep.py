"""Many episodes, in parallel and resumable: ``python -m scenarios.sweep``.

A sweep is the grid scenario x links x shape representation x controller x
environment seed x seed. Every cell is one `EpisodeSettings` and one recording,
``<out>/<episode_name(settings)>.mcap`` (``--formats mcap,rrd`` adds the .rrd)::

    python -m scenarios.sweep --scenario spheres --envs 200 \\
        --shapes ncedf,spheres,pointcloud:1000,pointcloud:5000 --out runs/table3
    python -m scenarios.sweep --scenario cluttered --links 4,5,7 --seeds 10 \\
        --controllers paper,release --out runs/table4

Resuming: an episode whose recordings (every requested format) are closed and
hold a final outcome (success, collision, stuck) is skipped; a missing, unclosed,
unreadable or interrupted one is run again and overwritten. The same command
finishes an interrupted sweep; on a finished one it only prints the summary.
After the episodes (also when interrupted), the sweep rewrites
``<out>/experiment.mcap`` (``scenarios.manifest``): the command, the date, the
machine and the package versions, which the tables of ``analysis/`` name.

Failures: episodes are independent. One that raises is reported on one line (its
settings and the error) and the others go on; the exit status is 1 if any failed.

Ctrl-C / SIGTERM: nothing more is started; local workers get ``STOP_GRACE_S``
seconds to record their current step and close their files (outcome
"interrupted"), Ray tasks end with the sweep's Ray job; the next sweep runs those
episodes again. One line says how many episodes are complete; exit status 130 / 143.

Locally (``--executor local``, the default) ``--workers`` spawned processes run
the episodes (default: one per core). JAX's CPU client sizes its thread pool from
the process's CPU affinity when it starts, so each worker narrows its affinity to
its share of the cores, starts the client, and widens the affinity again: the
pool keeps its size and the OS still spreads the workers over every core (a
parallel program then runs at CPU time / wall time 1.0 in a 1-core worker, 1.9
without the limit, on 2 cores). The installed jax 0.10 ignores
``XLA_FLAGS=--xla_cpu_multi_thread_eigen=false`` for this pool (1.8), and
``intra_op_parallelism_threads`` is not an XLA flag. Episodes are
submitted grouped by configuration (everything but the two seeds), so a worker
runs one configuration many times in a row and reuses the programs jitted for
it; the workers share a persistent JAX compilation cache (``<out>/.jax-cache``),
so a configuration compiles once per sweep rather than once per worker. A worker
is replaced after ``--recycle`` episodes: rerun-sdk keeps every finished
recording's threads alive until its process ends.

On a Ray cluster (``--executor ray [--address ADDR]``; ``pip install
'ncedf[cluster]'``) each episode is a task with one CPU. The workers write the
recordings themselves, so ``--out`` must be a folder every node sees at the same
path, and the package must be installed on every node. Without ``--address``,
Ray joins the cluster named by ``RAY_ADDRESS`` or starts one on this machine.

At the end a table gives, per scenario, links, representation and controller,
the outcome rates with their counts (read back from the recordings), the mean
solver time per step, and the episodes per hour of one worker (3600 / the mean
wall time of the episodes run this time, compilation included).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import functools
import importlib.util
import itertools
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
import warnings
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from tqdm import tqdm

from recorder import IncompleteRecordingWarning, RecorderError, RecordingInterrupted, load_run
from recorder.cli import (EXIT_STATUS, OneLineParser, Stopped, exit_with, one_line_warnings, path_text, positive,
                          stop_on_signals)
from recorder.recorder import FORMATS, check_creatable, output_paths
from scenarios import manifest

if TYPE_CHECKING:
    from scenarios.episode import EpisodeSettings

# scenarios.episode (and with it JAX) is imported inside the functions that need it: a worker
# process imports this module before its initializer runs, and JAX must not start before that.

#: Outcomes that end an episode for good; anything else (interrupted, none) is run again.
FINAL_OUTCOMES = ("success", "collision", "stuck")
DEFAULT_FORMATS = ("mcap",)
EXECUTORS = ("local", "ray")
#: Episodes a local worker process runs before it is replaced.
RECYCLE_EVERY = 50
#: Seconds running episodes get after Ctrl-C / SIGTERM to close their recordings.
STOP_GRACE_S = 10.0
#: Seconds between checks for finished episodes and signals.
POLL_S = 0.2
#: The persistent JAX compilation cache of a local sweep, under its output folder.
JAX_CACHE = ".jax-cache"
#: A worker drops its compiled programs once its memory maps pass this share of the kernel's limit
#: (:func:`release_programs`).
MAP_SHARE = 0.5
_SIGNALS = tuple(EXIT_STATUS)  # SIGINT, SIGTERM


#: Worker processes that may die (a crash, a kill) in a local sweep before it stops: after each, a fresh
#: pool runs the episodes the dead one left unfinished.
WORKER_DEATHS = 3


class SweepError(Exception):
    """A sweep that cannot go on (its workers kept dying); one line."""


# ---------------------------------------------------------------- the grid
def sweep_settings(
    scenarios: Sequence[str],
    links: Sequence[int],
    shapes: Sequence[str] | None = None,
    controllers: Sequence[str] | None = None,
    envs: int = 1,
    seeds: int = 1,
    **common,
) -> list[EpisodeSettings]:
    """Every episode of a sweep, grouped by configuration (env seeds 0..envs-1 and seeds 0..seeds-1 inner).

    Args:
      scenarios, links, shapes, controllers: the values of each axis (shapes, controllers: None = the
        `EpisodeSettings` default alone).
      envs, seeds: how many environment seeds and controller seeds.
      common: further `EpisodeSettings` fields shared by every episode (samples, horizon, max_steps,
        goal, model, options).
    Raises:
      ValueError naming the bad value (also from `EpisodeSettings`).
    """
    from scenarios.episode import EpisodeSettings

    shapes = (EpisodeSettings.shape,) if shapes is None else shapes
    controllers = (EpisodeSettings.controller,) if controllers is None else controllers
    for name, count in (("envs", envs), ("seeds", seeds)):
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {count!r}")
    for name, values in (("scenarios", scenarios), ("links", links), ("shapes", shapes),
                         ("controllers", controllers)):
        if not values:
            raise ValueError(f"{name} must not be empty")
    return [
        EpisodeSettings(scenario=scenario, links=n_links, shape=shape, controller=controller,
                        env_seed=env_seed, seed=seed, **common)
        for scenario, n_links, shape, controller in itertools.product(scenarios, links, shapes, controllers)
        for env_seed in range(envs)
        for seed in range(seeds)
    ]


def check_configurations(episodes: Sequence[EpisodeSettings]) -> None:
    """Build (`scenarios.episode.Episode`, nothing written) the first episode of every configuration,
    so that a bad shape, model, scenario option or obstacle file raises ValueError before a sweep starts."""
    from scenarios.episode import Episode

    checked = set()
    for settings in episodes:
        key = dataclasses.replace(settings, env_seed=0, seed=0)
        if key not in checked:
            checked.add(key)
            Episode(settings)


def one_line(exc: BaseException) -> str:
    """``Type: message`` on one line."""
    return " ".join(f"{type(exc).__name__}: {exc}".split())


def describe(settings: EpisodeSettings) -> str:
    """One line: the settings that are set (not None or empty)."""
    return ", ".join(f"{k}={v}" for k, v in settings.to_dict().items() if v not in (None, (), []))


# ---------------------------------------------------------------- recordings
@dataclasses.dataclass(frozen=True)
class Recorded:
    """What a complete recording says: its outcome and mean solver time per step (ms, NaN if absent)."""

    outcome: str
    solver_ms: float


def read_complete(stem: Path, formats: Sequence[str]) -> Recorded | None:
    """The episode recorded at `stem` (`stem.mcap`, `stem.rrd`) if every format's file is closed and
    holds a final outcome; None if one is missing, unclosed, unreadable or not final."""
    found = None
    for path in output_paths(stem, formats).values():
        if not path.is_file():
            return None
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", IncompleteRecordingWarning)
                run = load_run(path)
        except RecorderError:
            return None
        if not run.complete or run.outcome is None or run.outcome["outcome"] not in FINAL_OUTCOMES:
            return None
        solver = run.metrics["solver_ms"].mean() if "solver_ms" in run.metrics and len(run.metrics) else math.nan
        found = Recorded(run.outcome["outcome"], float(solver))
    return found


# ---------------------------------------------------------------- worker side
@functools.cache  # once per process
def start_jax(cores: int, cache_dir: str | None = None) -> None:
    """Start JAX's CPU client in this process with `cores` compute threads; call before any JAX work.

    XLA sizes its thread pool from the CPU affinity when the client starts: the affinity is narrowed
    to `cores` cores for the start and widened again after it, for every thread of the process.
    `cache_dir`: a persistent compilation cache shared with other processes.
    """
    pin = hasattr(os, "sched_setaffinity")
    if pin:
        allowed = os.sched_getaffinity(0)
        os.sched_setaffinity(0, sorted(allowed)[:cores])
    import jax

    try:
        jax.devices()
    finally:
        if pin:
            for tid in os.listdir("/proc/self/task"):
                try:
                    os.sched_setaffinity(int(tid), allowed)
                except OSError:  # the thread has ended
                    pass
    if cache_dir is not None:
        from ncedf.compile_cache import use_folder

        use_folder(cache_dir)  # shared with the other workers


def _init_local_worker(cores: int, cache_dir: str) -> None:
    # Ctrl-C reaches the whole process group: an idle worker ignores it (no traceback); a running
    # episode's recorder catches it, records the step and closes its files.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # tqdm would create a multiprocessing lock (a named semaphore) that a worker stopped by a signal
    # leaves behind ("leaked semaphore" warnings at exit); this process's bars only need a thread lock.
    tqdm.set_lock(threading.RLock())
    start_jax(cores, cache_dir)


def release_programs(share: float | None = None) -> bool:
    """Clear JAX's compiled programs in this process (``jax.clear_caches``; the persistent cache loads
    them again) where its memory maps exceed ``share`` (default ``MAP_SHARE``) of the kernel's limit,
    ``vm.max_map_count``: compiled programs keep their own maps, and a process at the limit dies
    compiling the next one. Linux only (elsewhere nothing); returns whether it cleared."""
    try:
        limit = int(Path("/proc/sys/vm/max_map_count").read_text())
        with open("/proc/self/maps", "rb") as maps:
            count = sum(1 for _ in maps)
    except (OSError, ValueError):
        return False
    if count <= (MAP_SHARE if share is None else share) * limit:
        return False
    import jax

    jax.clear_caches()
    return True


def run_one(settings: EpisodeSettings, stem: str,
            formats: Sequence[str]) -> tuple[float, str | None, str | None]:
    """Run one episode into `stem` (overwriting) -> (wall seconds, None or the error on one line, None or
    the signal that stopped it); then :func:`release_programs`, as a worker runs many. An obstacle file's
    mesh and goal warnings are not repeated: the sweep's check (`check_configurations`, unless
    ``run_sweep(check=False)``) showed them before the workers started."""
    from scenarios.episode import GoalWarning, run_episode
    from scenarios.mesh_check import MeshWarning

    start = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MeshWarning)
            warnings.simplefilter("ignore", GoalWarning)
            result = run_episode(settings, out=stem, formats=tuple(formats), overwrite=True)
    except Exception as exc:  # reported by the sweep; the other episodes go on
        return time.perf_counter() - start, one_line(exc), None
    finally:
        release_programs()
    return time.perf_counter() - start, None, result.signal


#: The signal that stopped an episode in this pool worker, once one has (its recorder caught it).
_SIGNALLED: list[signal.Signals] = []


def _end_worker(signum: signal.Signals) -> None:
    """End this process by `signum` as if no recorder had caught it (by its exit status where it is blocked)."""
    signal.signal(signum, signal.SIG_DFL)
    signal.raise_signal(signum)
    os._exit(128 + signum)


def _local_episode(settings: EpisodeSettings, stem: str, formats: Sequence[str]) -> tuple[float, str | None]:
    """:func:`run_one` in a local pool's worker. A worker whose episode a signal stopped ends at its next
    episode, before writing anything: the pool may already have queued one for it, which the stopping
    sweep would kill half-written (a worker signalled alone breaks its pool: its round runs again)."""
    if _SIGNALLED:
        _end_worker(_SIGNALLED[0])
    seconds, error, signame = run_one(settings, stem, formats)
    if signame:
        _SIGNALLED.append(signal.Signals[signame])
    return seconds, error


def _ray_episode(settings: EpisodeSettings, stem: str, formats: Sequence[str],
                 cache_dir: str | None) -> tuple[float, str | None]:
    start_jax(1, cache_dir)
    return run_one(settings, stem, formats)[:2]


# ---------------------------------------------------------------- executors
OnDone = Callable[["EpisodeSettings", float, "str | None"], None]


class _Stop:
    """While entered, SIGINT and SIGTERM only record the first signal (`signum`) for the sweep loop."""

    def __init__(self):
        self.signum: int | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum

    def __enter__(self) -> _Stop:
        if threading.current_thread() is threading.main_thread():
            for sig in _SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def ray_missing() -> str | None:
    """Why ``--executor ray`` cannot run here (Ray is not installed), or None."""
    return None if importlib.util.find_spec("ray") else "--executor ray needs Ray: pip install 'ncedf[cluster]'"


def _cpu_count() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _run_local(todo: list[EpisodeSettings], out: Path, formats, workers: int, recycle: int,
               cache_dir: str | None, on_done: OnDone, log: Callable[[str], None]) -> int | None:
    """Run `todo` in `workers` spawned processes; returns the signal that stopped it, or None.

    Workers are recycled by running rounds of ``workers * recycle`` episodes, each in a fresh pool:
    ``max_tasks_per_child`` deadlocks once a worker reaches its limit (CPython gh-115634, 3.11-3.14).
    Where a worker dies (a crash, a kill), the round's other workers are killed and the episodes it
    left unfinished run again in a fresh pool, at most ``WORKER_DEATHS`` times (then SweepError).
    """
    out.mkdir(parents=True, exist_ok=True)
    per_round, queue, deaths = workers * recycle, list(todo), 0
    with _Stop() as stop:
        while queue and stop.signum is None:
            left = _run_round(queue[:per_round], out, formats, workers, cache_dir, on_done, stop)
            queue = left + queue[per_round:]
            if left:
                deaths += 1
                log(f"a worker process died (killed, or out of memory?); {len(left)} episodes run again")
            if deaths > WORKER_DEATHS:
                raise SweepError(f"worker processes died {deaths} times (killed, or out of memory?)")
    return stop.signum


def _run_round(todo: list[EpisodeSettings], out: Path, formats, workers: int, cache_dir: str | None,
               on_done: OnDone, stop: _Stop) -> list[EpisodeSettings]:
    """One pool of `workers` spawned processes for `todo`, shut down at the end or on `stop`; the
    episodes left unfinished where a worker died (none otherwise)."""
    from scenarios.episode import episode_name

    cores = max(1, _cpu_count() // workers)
    before = set(multiprocessing.active_children())
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                  initializer=_init_local_worker, initargs=(cores, cache_dir))
    futures = {pool.submit(_local_episode, s, str(out / episode_name(s)), formats): s for s in todo}
    pending, left = set(futures), []
    try:
        while pending and stop.signum is None and not left:
            done, pending = cf.wait(pending, timeout=POLL_S, return_when=cf.FIRST_COMPLETED)
            if stop.signum is not None:  # episodes that ended with the signal are sorted out by the caller
                break
            for future in done:
                try:
                    seconds, error = future.result()
                except RecordingInterrupted:  # a worker was signalled on its own: run it again later
                    seconds, error = math.nan, "interrupted by a signal"
                except cf.process.BrokenProcessPool:  # a worker died: every unfinished episode is left
                    left.append(futures[future])
                    continue
                on_done(futures[future], seconds, error)
        return left + [futures[f] for f in pending] if left else []
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
        if left or pending:  # a broken pool's workers outlive it (an episode's SIGTERM handler keeps them);
            # they get no grace: the episodes they run are run again
            _stop_workers(set(multiprocessing.active_children()) - before, 0.0 if left else STOP_GRACE_S)
        pool.shutdown(wait=True)


def _stop_workers(workers, grace: float) -> None:
    """SIGTERM: each worker's recorder records the current step and closes; kill those still running after
    ``grace`` seconds."""
    for process in workers:
        process.terminate()
    deadline = time.monotonic() + grace
    for process in workers:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join()


def _run_ray(todo: list[EpisodeSettings], out: Path, formats, address: str | None, recycle: int,
             cache_dir: str | None, on_done: OnDone) -> int | None:
    """One Ray task per episode on the cluster at `address` (or the one Ray finds or starts)."""
    import ray

    from scenarios.episode import episode_name

    started = not ray.is_initialized()
    if started:
        try:
            with warnings.catch_warnings():  # Ray starts its processes by fork + exec, which is safe
                warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
                ray.init(address=address, include_dashboard=False, logging_level="ERROR")
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise ValueError(f"cannot start or reach Ray at {address or 'RAY_ADDRESS or this machine'}: "
                             f"{one_line(exc)}") from None
    out.mkdir(parents=True, exist_ok=True)
    task = ray.remote(num_cpus=1, max_calls=recycle)(_ray_episode)
    try:
        with _Stop() as stop:
            refs = {task.remote(s, str(out / episode_name(s)), tuple(formats), cache_dir): s for s in todo}
            pending = list(refs)
            while pending and stop.signum is None:
                done, pending = ray.wait(pending, num_returns=len(pending), timeout=POLL_S)
                if stop.signum is not None:
                    break
                for ref in done:
                    try:
                        seconds, error = ray.get(ref)
                    except ray.exceptions.RayError as exc:
                        seconds, error = math.nan, one_line(exc)
                    on_done(refs[ref], seconds, error)
            if pending and not started:  # else ray.shutdown() ends this job's tasks
                for ref in pending:
                    ray.cancel(ref, force=True)
    finally:
        if started:
            ray.shutdown()
    return stop.signum


# ---------------------------------------------------------------- the sweep
@dataclasses.dataclass
class EpisodeStatus:
    """One episode of a sweep: `state` is "skipped" (complete before), "run", "failed" or "pending"
    (not run: interrupted or stopped); `recorded` for skipped and run ones; `seconds` wall time of a run."""

    settings: EpisodeSettings
    state: str = "pending"
    recorded: Recorded | None = None
    seconds: float = math.nan
    error: str | None = None


@dataclasses.dataclass
class SweepReport:
    """What a sweep did. `workers`: local worker processes (None on Ray); `seconds`: wall time;
    `signum`: the signal that stopped it; `error`: why it stopped early."""

    out: Path
    episodes: list[EpisodeStatus]
    executor: str
    workers: int | None = None
    seconds: float = 0.0
    signum: int | None = None
    error: str | None = None

    def count(self, state: str) -> int:
        return sum(e.state == state for e in self.episodes)

    @property
    def where(self) -> str:
        if self.workers is None:
            return self.executor
        return f"{self.workers} local worker{'s' * (self.workers > 1)}"

    @property
    def exit_status(self) -> int:
        if self.signum is not None:
            return 128 + self.signum
        return 1 if self.error or self.count("failed") else 0


def run_sweep(
    episodes: Sequence[EpisodeSettings],
    out: str | Path,
    formats: Sequence[str] = DEFAULT_FORMATS,
    *,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    recycle: int = RECYCLE_EVERY,
    progress: bool = True,
    check: bool = True,
    jax_cache: str | Path | None = None,
) -> SweepReport:
    """Run the episodes whose recordings under `out` are not complete; see the module docstring.

    Args:
      episodes: from `sweep_settings` (or any list; its order is the order of submission).
      out: the folder of the recordings (created).
      formats: recording formats, a non-empty subset of ("rrd", "mcap").
      executor: "local" (worker processes) or "ray".
      workers: local worker processes (default: one per core).
      address: Ray cluster address.
      recycle: episodes per local worker process (Ray: per worker) before it is replaced.
      progress: a tqdm progress bar with an ETA, and one line per failure, on stderr.
      check: first build one episode of every configuration to run (`check_configurations`).
      jax_cache: folder of the persistent JAX compilation cache the workers share. None: locally
        `<out>/.jax-cache`; on Ray none (compiled CPU programs are only safe to share between machines
        with the same CPU features).
    Raises:
      ValueError naming a bad argument or setting, or an episode given twice (before anything is written).
    """
    from scenarios.episode import episode_name

    formats, workers, out = _checked_arguments(episodes, out, formats, executor, workers, recycle)
    start = time.perf_counter()
    report = SweepReport(out, [EpisodeStatus(s) for s in episodes], executor)
    for episode in report.episodes:
        episode.recorded = read_complete(out / episode_name(episode.settings), formats)
        if episode.recorded is not None:
            episode.state = "skipped"
    todo = {e.settings: e for e in report.episodes if e.state == "pending"}
    if executor == "local":
        workers = report.workers = min(workers, max(1, len(todo)))

    def log(line: str) -> None:
        if progress:
            tqdm.write(line, file=sys.stderr)

    if check:
        check_configurations(list(todo))
    log(f"{len(report.episodes)} episodes in {out}: {report.count('skipped')} complete, {len(todo)} to run "
        f"({report.where})")
    if todo:
        _run_todo(report, todo, out, formats, workers, address, recycle, progress, jax_cache, log)
    report.seconds = time.perf_counter() - start
    return report


def _checked_arguments(episodes, out, formats, executor: str, workers, recycle) -> tuple[tuple, int, Path]:
    """``run_sweep``'s formats, worker count and resolved output folder; ValueError naming a bad one."""
    from scenarios.episode import episode_name

    formats = tuple(formats)
    if not formats or set(formats) - set(FORMATS):
        raise ValueError(f"formats must be a non-empty subset of {', '.join(FORMATS)}, got {','.join(formats)!r}")
    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    workers = _cpu_count() if workers is None else workers
    for name, value in (("workers", workers), ("recycle", recycle)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    repeated = [name for name, n in Counter(map(episode_name, episodes)).items() if n > 1]
    if repeated:
        raise ValueError(f"episode {repeated[0]} is given more than once (a repeated value?)")
    out = Path(out).resolve()
    try:
        check_creatable(out, "recordings")
    except RecorderError as exc:
        raise ValueError(str(exc)) from None
    return formats, workers, out


def _run_todo(report: SweepReport, todo: dict, out: Path, formats: tuple, workers: int, address, recycle: int,
              progress: bool, jax_cache, log) -> None:
    """Run the ``todo`` episodes (settings -> EpisodeStatus) on the report's executor, updating their
    statuses and the report's signal or error."""
    from scenarios.episode import episode_name

    executor = report.executor
    with tqdm(total=len(todo), unit="episode", disable=not progress, dynamic_ncols=True) as bar:
        def on_done(settings: EpisodeSettings, seconds: float, error: str | None) -> None:
            episode = todo[settings]
            episode.seconds = seconds
            if error is None:
                episode.recorded = read_complete(out / episode_name(settings), formats)
                if episode.recorded is None:
                    error = "the episode ended without a complete recording with a final outcome"
            episode.state, episode.error = ("run", None) if error is None else ("failed", error)
            if error is not None:
                log(f"failed: {episode_name(settings)} ({describe(settings)}): {error}")
            bar.update()
            bar.set_postfix(failed=report.count("failed"), refresh=False)

        try:
            if executor == "local":
                cache = str(out / JAX_CACHE if jax_cache is None else Path(jax_cache).resolve())
                report.signum = _run_local(list(todo), out, formats, workers, recycle, cache, on_done, log)
            else:
                cache = None if jax_cache is None else str(Path(jax_cache).resolve())
                report.signum = _run_ray(list(todo), out, formats, address, recycle, cache, on_done)
        except SweepError as exc:
            report.error = str(exc)
    for episode in todo.values():  # finished while the sweep was stopping
        if episode.state == "pending":
            episode.recorded = read_complete(out / episode_name(episode.settings), formats)
            if episode.recorded is not None:
                episode.state = "run"


# ---------------------------------------------------------------- summary
_GROUP = ("scenario", "links", "shape", "controller")


def summary_table(report: SweepReport) -> str:
    """Per scenario, links, representation and controller: episodes, outcome rates (counts), failed,
    mean solver ms per step, and episodes per hour of one worker (from the episodes run this time)."""
    groups: dict[tuple, list[EpisodeStatus]] = {}
    for episode in report.episodes:
        groups.setdefault(tuple(getattr(episode.settings, k) for k in _GROUP), []).append(episode)
    header = [*_GROUP, "episodes", *FINAL_OUTCOMES, "failed", "solver ms", "episodes/h/worker"]
    rows = []
    for key, members in groups.items():
        recorded = [e.recorded for e in members if e.recorded is not None]
        outcomes = Counter(r.outcome for r in recorded)
        rates = [f"{outcomes[o] / len(recorded):.3f} ({outcomes[o]})" if recorded else "-" for o in FINAL_OUTCOMES]
        solver = [r.solver_ms for r in recorded if math.isfinite(r.solver_ms)]
        timed = [e.seconds for e in members if e.state == "run" and math.isfinite(e.seconds)]
        rows.append([*map(str, key), str(len(recorded)), *rates, str(sum(e.state == "failed" for e in members)),
                     f"{sum(solver) / len(solver):.1f}" if solver else "-",
                     f"{3600 * len(timed) / sum(timed):.0f}" if timed else "-"])
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header, *rows]]
    ran = report.count("run")
    rate = f", {3600 * ran / report.seconds:.0f} episodes/h" if ran else ""
    lines.append(f"{report.count('run')} run, {report.count('skipped')} complete before, "
                 f"{report.count('failed')} failed in {report.seconds:.0f} s{rate} "
                 f"({report.where}); recordings in {report.out}")
    return "\n".join(lines)


# ---------------------------------------------------------------- CLI
def _csv(kind: Callable, what: str) -> Callable[[str], tuple]:
    def parse(text: str) -> tuple:
        items = [item.strip() for item in text.split(",")]
        try:
            if "" in items:
                raise ValueError
            return tuple(kind(item) for item in items)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {text!r}") from None

    return parse


def _option(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, value


def parse_args(argv=None) -> argparse.Namespace:
    from ncedf.presets import PRESETS
    from ncedf.shapes import REPRESENTATIONS
    from scenarios.episode import GOALS, SCENARIOS, EpisodeSettings

    controllers = tuple(PRESETS)

    # No abbreviations: a runner's --seed or --shape would be read as --seeds or --shapes.
    p = OneLineParser(prog="python -m scenarios.sweep", description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                epilog="Exit status: 0 all episodes complete, 1 some failed, 2 bad arguments, "
                                       "130/143 interrupted (run the same command again to finish).")
    grid = p.add_argument_group("the grid (comma-separated values)")
    grid.add_argument("--scenario", type=_csv(str, "scenario names"), required=True,
                      help=f"scenario(s): {', '.join(SCENARIOS)}")
    grid.add_argument("--links", type=_csv(int, "integers"), default=(4,), help="link counts (default 4)")
    grid.add_argument("--shapes", type=_csv(str, "representations"),
                      help=f"robot-shape representations: {', '.join(REPRESENTATIONS)} "
                           f"(default {EpisodeSettings.shape})")
    grid.add_argument("--controllers", type=_csv(str, "controller names"),
                      help=f"MPPI presets: {', '.join(controllers)} (default {EpisodeSettings.controller})")
    grid.add_argument("--envs", type=positive, default=1, help="environment seeds 0..N-1 (default 1)")
    grid.add_argument("--seeds", type=positive, default=1, help="controller seeds 0..N-1 (default 1)")
    ep = p.add_argument_group("every episode")
    ep.add_argument("--samples", type=positive, help="MPPI rollouts (default: the controller's)")
    ep.add_argument("--horizon", type=positive, help="MPPI horizon (default: the controller's)")
    ep.add_argument("--max-steps", type=positive, help="step budget (default: the scenario's)")
    ep.add_argument("--goal", metavar="GOAL", help=f"{', '.join(GOALS)} or X,Y,Z in m (spheres and cluttered; "
                                                   f"default {EpisodeSettings.goal})")
    ep.add_argument("--model", type=path_text,
                    help="N-CEDF weights: the robot's links and its network (default: the shipped model)")
    ep.add_argument("--option", type=_option, action="append", default=[], metavar="KEY=VALUE",
                    help=f"scenario option, repeatable (e.g. custom: obstacles=FILE[{os.pathsep}FILE...], "
                         "absolute paths for Ray)")
    run = p.add_argument_group("running")
    run.add_argument("--out", required=True, type=path_text, help="folder of the recordings")
    run.add_argument("--formats", type=_csv(str, "formats"), default=DEFAULT_FORMATS,
                     help=f"recording formats, of {', '.join(FORMATS)} (default mcap)")
    run.add_argument("--executor", choices=EXECUTORS, default="local")
    run.add_argument("--workers", type=positive, help=f"local worker processes (default: one per core, {_cpu_count()})")
    run.add_argument("--address", help="Ray cluster address (default: RAY_ADDRESS, or a local Ray)")
    run.add_argument("--recycle", type=positive, default=RECYCLE_EVERY,
                     help=f"episodes per worker process before it is replaced (default {RECYCLE_EVERY})")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    command = "python -m scenarios.sweep " + " ".join(sys.argv[1:] if argv is None else argv)
    # Outside the sweep loop (checks before it, the summary after it) a signal stops at once.
    try:
        with stop_on_signals(), one_line_warnings(once=(UserWarning,)):  # not once per configuration checked
            return _main(args, command)
    except Stopped as exc:
        print(f"stopped by {exc}; recordings already complete are kept", file=sys.stderr)
        return EXIT_STATUS[exc.signum]


def _main(args: argparse.Namespace, command: str) -> int:
    model = str(Path(args.model).resolve()) if args.model else None  # rerunnable from anywhere, any node
    common = {k: v for k, v in (("samples", args.samples), ("horizon", args.horizon),
                                ("max_steps", args.max_steps), ("goal", args.goal), ("model", model))
              if v is not None}
    if args.option:
        common["options"] = tuple(args.option)
    if args.executor == "ray":
        if why := ray_missing():
            print(f"error: {why}", file=sys.stderr)
            return 2
    elif args.address is not None:
        print("error: --address is for --executor ray", file=sys.stderr)
        return 2
    if args.executor == "ray" and args.workers is not None:
        print("error: --workers is for --executor local (Ray runs one episode per CPU of the cluster)",
              file=sys.stderr)
        return 2
    try:
        episodes = sweep_settings(args.scenario, args.links, args.shapes, args.controllers, args.envs, args.seeds,
                                  **common)
        report = run_sweep(episodes, args.out, args.formats, executor=args.executor, workers=args.workers,
                           address=args.address, recycle=args.recycle)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    # After the sweep: the manifest starts JAX (the machine's device), which the workers must own first.
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    manifest.write_manifest(args.out, "sweep", command, {**settings, "episodes": len(episodes)})
    if report.signum is not None:
        complete = report.count("skipped") + report.count("run")
        print(f"interrupted by {signal.Signals(report.signum).name}: {complete} of {len(report.episodes)} episodes "
              f"complete in {report.out} ({report.count('run')} from this run); run the same command to finish",
              file=sys.stderr)
        return report.exit_status
    print(summary_table(report))
    if report.error:
        print(f"error: {report.error}; {report.count('pending')} episodes not run: run the same command again",
              file=sys.stderr)
    return report.exit_status


if __name__ == "__main__":
    # Run the importable module's `main`: functions sent to workers (Ray pickles them by reference)
    # must live in `scenarios.sweep`, not in `__main__`.
    from scenarios.sweep import main as module_main

    exit_with(module_main())
