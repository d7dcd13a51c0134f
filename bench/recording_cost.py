"""Recorder benchmark: logging overhead per step, file sizes, and `load_runs` over many runs.

    python bench/recording_cost.py                          # 7 links, 300 steps, MCAP mesh every 1, 2, 5 steps
    python bench/recording_cost.py --mcap-mesh-every 1 --steps 100
    python bench/recording_cost.py --load-runs 4000         # also time load_runs over 4000 small runs

Synthetic 7-link data (`recorder.synthetic`): a mesh of 7 tubes x 30 rings x 32 points = 6720
vertices, 500 obstacle points, a 20-point plan, backbone lines, state and metrics. The step data
is made before timing; the time covers `log_step` (conversion included) plus opening and
closing the files, for the Rerun sink alone, the MCAP sink alone and both. The budget is
3 ms per step with both sinks; each line prints its ratio to it (CPU time, see `time_run`).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
import tempfile
import time
from pathlib import Path

from recorder import Recorder, load_runs
from recorder.cli import OneLineParser, exit_with, stoppable
from recorder.synthetic import SyntheticRun

from arguments import non_negative, positive

BUDGET_MS = 3.0
CONFIGS = {"rrd": ("rrd",), "mcap": ("mcap",), "both": ("rrd", "mcap")}


def time_run(folder: Path, name: str, formats, run: SyntheticRun, steps: list[dict], mcap_mesh_every: int,
             flush_every: int) -> tuple[float, float]:
    """Record `steps` once; (wall, CPU) seconds from opening to closed files.

    CPU time is this process's, all threads (Rerun's writer threads, zstd) included: the cost the
    recorder takes from the controller, and less disturbed than wall time on a busy machine.
    """
    start, cpu = time.perf_counter(), time.process_time()
    with Recorder(folder / name, run.meta, formats=formats, mcap_mesh_every=mcap_mesh_every,
                  flush_every=flush_every,
                  safety_margin=0.02, overwrite=True) as rec:
        for k, kwargs in enumerate(steps):
            rec.log_step(k, 0.05 * k, **kwargs)
        rec.finish({"outcome": "success", "steps": len(steps)})
    return time.perf_counter() - start, time.process_time() - cpu


def bench_logging(args, folder: Path) -> None:
    run = SyntheticRun(links=args.links, seed=0)
    steps = [run.step(k) for k in range(args.steps)]
    print(f"{args.links} links, mesh {run.triangles.max() + 1} vertices / {len(run.triangles)} triangles, "
          f"{run.n_points} obstacle points, {run.horizon}-point plan, {args.steps} steps, best of {args.repeat}")
    print(f"{'mcap_mesh_every':>15} {'sink':>5} {'wall ms/step':>13} {'CPU ms/step':>12} {'CPU x budget':>13} "
          f"{'MB/100 steps':>24}")
    time_run(folder, "warmup", ("rrd", "mcap"), run, steps[:5], 1, args.flush_every)  # imports, first chunk
    for mesh_every in args.mcap_mesh_every:
        for label, formats in CONFIGS.items():
            if label == "rrd" and mesh_every != args.mcap_mesh_every[0]:
                continue  # the Rerun sink logs the mesh every step whatever the MCAP interval
            name = f"{label}-{mesh_every}"
            times = [time_run(folder, name, formats, run, steps, mesh_every, args.flush_every)
                     for _ in range(args.repeat)]
            wall, cpu = (min(t[i] for t in times) / args.steps * 1e3 for i in (0, 1))
            sizes = ", ".join(f"{fmt} {(folder / f'{name}.{fmt}').stat().st_size / args.steps * 100 / 1e6:.1f}"
                              for fmt in formats)
            print(f"{mesh_every:>15} {label:>5} {wall:>13.2f} {cpu:>12.2f} {cpu / BUDGET_MS:>13.2f} {sizes:>24}")


def write_runs(folder: Path, fmt: str, first: int, count: int, links: int, n_steps: int) -> None:
    """Runs first .. first + count - 1 (state, metrics, backbone, cloud, plan; no mesh)."""
    run = SyntheticRun(links=links, seed=0)
    steps = [{k: v for k, v in run.step(k).items() if k not in ("mesh_vertices", "mesh_triangles")}
             for k in range(n_steps)]
    for i in range(first, first + count):
        with Recorder(folder / fmt / f"run{i:05d}", {**run.meta, "seed": i}, formats=(fmt,)) as rec:
            for k, kwargs in enumerate(steps):
                rec.log_step(k, 0.05 * k, **kwargs)
            rec.finish({"outcome": "success", "steps": n_steps})


def bench_load_runs(args, folder: Path) -> None:
    """N runs of `--load-steps` steps per format, then `load_runs` over each folder.

    The runs are written by short-lived worker processes (250 runs each): rerun-sdk keeps every
    recording's threads alive until its process ends (rerun-io/rerun#2116).
    """
    start = time.perf_counter()
    batch = 250
    with ProcessPoolExecutor(max_workers=1, max_tasks_per_child=1) as pool:
        jobs = [pool.submit(write_runs, folder, fmt, first, min(batch, args.load_runs - first), args.links,
                            args.load_steps)
                for fmt in ("rrd", "mcap") for first in range(0, args.load_runs, batch)]
        for job in jobs:
            job.result()
    print(f"wrote 2 x {args.load_runs} runs of {args.load_steps} steps in {time.perf_counter() - start:.0f} s")
    for fmt in ("mcap", "rrd"):
        start = time.perf_counter()
        runs, table = load_runs(folder / fmt)
        elapsed = time.perf_counter() - start
        assert len(runs) == args.load_runs and len(table) == args.load_runs * args.load_steps
        print(f"load_runs over {len(runs)} .{fmt} runs: {elapsed:.2f} s ({elapsed / len(runs) * 1e3:.2f} ms/run), "
              f"steps table {table.shape}")


def main() -> None:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--links", type=positive, default=7)
    parser.add_argument("--steps", type=positive, default=300)
    parser.add_argument("--mcap-mesh-every", type=positive, nargs="+", default=[1, 2, 5])
    parser.add_argument("--flush-every", type=positive, default=50)
    parser.add_argument("--repeat", type=positive, default=3, help="runs per configuration; the best is kept")
    parser.add_argument("--load-runs", type=non_negative, default=0, help="also time load_runs over this many runs")
    parser.add_argument("--load-steps", type=positive, default=20)
    parser.add_argument("--skip-logging", action="store_true", help="only the load_runs benchmark")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_logging:
            bench_logging(args, Path(tmp))
        if args.load_runs:
            bench_load_runs(args, Path(tmp))


if __name__ == "__main__":
    exit_with(stoppable(main))
