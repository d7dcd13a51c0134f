"""MPPI step time of the paper's timed configurations on this machine's JAX device, beside the paper's figures.

    python bench/paper_timing.py                      # Tables III and IV, 30 steps per controller
    python bench/paper_timing.py --tables 4 --links 4 --steps 10
    python bench/paper_timing.py --shapes ncedf,spheres,pointcloud:1000 --json timing.json

The paper timed its controller on an RTX 4090 (``analysis.paper``); this bench
times the same configurations on the device JAX runs on here (CPU or GPU, the
code unchanged), one group of controllers per scene, with every controller of a
group stepped in turn (``solver_time.solver_times``: the scene's start, the
cloud at each step's time, compilation not timed):

  Table III: the dynamic spheres, 4 links, environment 0, fixed goal; the
    release controller (1000 rollouts, H 12) with each robot representation
    of ``--shapes`` (paper: N-CEDF 6 ms, spheres 5, point cloud 1000 62,
    point cloud 5000 284), and ``ours`` with the N-CEDF;
  Table IV: the cluttered scene with 4, 5 and 7 links, the N-CEDF with the
    ``paper`` (800, H 20), ``release`` and ``ours`` controllers (paper: 33.1,
    41.9 and 60.7 ms). Table I's MPPI column times the paper's setting with
    4 links and about 500 points: the Table IV 4-link ``paper`` row.

Printed per row: the representation, controller and its rollouts and horizon,
the median and mean +- std of the step time (ms), the paper's figure for the
row's table (ms) and the ratio of our median to it. Episode outcomes are not
measured here (``bench/closed_loop.py``, ``scenarios.sweep``). Ctrl-C prints
the groups finished so far and exits 130 (SIGTERM: 143).

Its figures on this project's machines (a 2-core CPU, an H200) are in ``docs/experiments.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys

import jax
import numpy as np

from analysis import paper
from recorder.cli import EXIT_STATUS, OneLineParser, Stopped, exit_with, stop_on_signals
from scenarios.episode import Episode, EpisodeSettings

from arguments import output_file, parse_list, positive
from solver_time import solver_times

#: Table III's representations, in the paper's order.
TABLE3_SHAPES = tuple(paper.TABLE3)
#: Table IV's controllers, timed with the N-CEDF.
TABLE4_CONTROLLERS = ("paper", "release", "ours")


@dataclasses.dataclass(frozen=True)
class Group:
    """Controllers timed together on one scene: ``rows`` maps a row label to (settings, paper ms)."""

    table: str
    scene: str
    rows: dict[str, tuple[EpisodeSettings, float]]


def groups(tables: list[int], shapes: list[str], links: list[int]) -> list[Group]:
    """The timed groups of ``tables`` (3, 4), in order."""
    out = []
    if 3 in tables:
        base = EpisodeSettings("spheres", 4, 0, env_seed=0, goal="fixed")
        rows = {f"{shape} release": (dataclasses.replace(base, shape=shape, controller="release"),
                                     round(paper.TABLE3[shape][3] * 1e3, 6)) for shape in shapes}
        rows["ncedf ours"] = (dataclasses.replace(base, controller="ours"), round(paper.TABLE3["ncedf"][3] * 1e3, 6))
        out.append(Group("III", "spheres L4", rows))
    if 4 in tables:
        for n in links:
            base = EpisodeSettings("cluttered", n, 0)
            out.append(Group("IV", f"cluttered L{n}", {
                f"ncedf {c}": (dataclasses.replace(base, controller=c), round(paper.TABLE4[n][0] * 1e3, 6))
                for c in TABLE4_CONTROLLERS}))
    return out


def time_group(group: Group, steps: int) -> list[dict]:
    """One result row per controller of ``group``: sizes, step ms (median, mean, std), paper ms, ratio."""
    prepared = {label: Episode(s) for label, (s, _) in group.rows.items()}
    times = solver_times(prepared, steps)
    out = []
    for label, (settings, paper_ms) in group.rows.items():
        t = times[label]
        samples, horizon = prepared[label].scene.config.mppi.samples, prepared[label].scene.config.mppi.horizon
        median = float(np.median(t))
        out.append({"table": group.table, "scene": group.scene, "row": label, "shape": settings.shape,
                    "controller": settings.controller, "samples": samples, "horizon": horizon,
                    "median_ms": median, "mean_ms": float(t.mean()), "std_ms": float(t.std()),
                    "paper_ms": paper_ms, "ratio": median / paper_ms, "steps": int(t.size)})
    return out


HEADER = (f"{'table':<6}{'scene':<13}{'representation':<17}{'controller':<10}{'N':>6}{'H':>4}{'median ms':>11}"
          f"{'mean +- std ms':>19}{'paper ms':>10}{'ratio':>8}")


def format_row(r: dict) -> str:
    return (f"{r['table']:<6}{r['scene']:<13}{r['shape']:<17}{r['controller']:<10}{r['samples']:>6}{r['horizon']:>4}"
            f"{r['median_ms']:>11.1f}{r['mean_ms']:>11.1f} +- {r['std_ms']:<5.1f}{r['paper_ms']:>10.1f}"
            f"{r['ratio']:>8.2f}")


def device_line() -> str:
    d = jax.devices()[0]
    return (f"{d.platform} {d.device_kind} ({len(jax.devices())} visible); jax {jax.__version__}, "
            f"python {platform.python_version()}; paper: {paper.HARDWARE}")


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tables", default="3,4", type=lambda t: parse_list(t, int, "table", (3, 4)),
                   help="paper tables to time: 3, 4 or 3,4 (default 3,4)")
    p.add_argument("--shapes", default=",".join(TABLE3_SHAPES),
                   type=lambda t: parse_list(t, str, "representation", TABLE3_SHAPES),
                   help=f"Table III representations (default {','.join(TABLE3_SHAPES)})")
    p.add_argument("--links", default="4,5,7", type=lambda t: parse_list(t, int, "links", tuple(paper.TABLE4)),
                   help="Table IV link counts (default 4,5,7)")
    p.add_argument("--steps", type=positive, default=30, help="timed steps per controller (default 30)")
    p.add_argument("--json", type=output_file, help="also write the rows here")
    args = p.parse_args(argv)

    print(f"device: {device_line()}", flush=True)
    print(HEADER, flush=True)
    rows = []
    try:
        with stop_on_signals():
            for group in groups(args.tables, args.shapes, args.links):
                done = time_group(group, args.steps)
                rows.extend(done)
                print("\n".join(map(format_row, done)), flush=True)
    except Stopped as stop:
        print(f"interrupted ({stop}): {len(rows)} rows timed, printed above", file=sys.stderr)
        return EXIT_STATUS[stop.signum]
    if args.json:
        args.json.write_text(json.dumps({"device": device_line(), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    exit_with(main())
