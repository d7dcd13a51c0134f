"""The options every scenario runner shares, and the run -> summary -> exit-status flow.

A runner builds its parser with :func:`make_parser`, adds its own options, and
calls :func:`run_cli` with a function that turns the parsed arguments into
:class:`~scenarios.episode.EpisodeSettings`.

Everything is validated (settings, model file, scenario files, output paths)
before any file is opened; a bad value prints one line ``error: ...`` naming it
and exits 2. Ctrl-C / SIGTERM: during the run the recorder finishes the step,
writes the outcome ``interrupted`` and closes the files; one line says what was
kept; exit 130 (SIGINT) or 143 (SIGTERM). A warning about a user's file (an
open mesh, say) prints one line ``warning: ...``.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
from pathlib import Path
from typing import Callable

from ncedf.compile_cache import add_cache_option, enable_compile_cache
from ncedf.presets import DEFAULT, PRESETS, SUMMARIES
from recorder import RecorderError
from recorder.cli import (EXIT_STATUS, OneLineParser, Stopped, one_line_warnings, path_text, positive,
                          stop_on_signals)
from recorder.recorder import FORMATS, check_writable, output_paths
from scenarios.episode import Episode, EpisodeResult, EpisodeSettings


def make_parser(scenario: str, description: str, *, links: int = 4, max_steps: int) -> OneLineParser:
    """A parser with the shared options (scenario options are added by the runner).

    Args:
      scenario: the runner's name (``python -m scenarios.<scenario>``).
      description: --help text.  links: default link count.  max_steps: the scenario's step budget.
    """
    controllers = "\n".join(f"  {name:8s} {summary}" for name, summary in SUMMARIES.items())
    p = OneLineParser(prog=f"python -m scenarios.{scenario}", description=description,
                      epilog=f"controllers (--controller):\n{controllers}",
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--links", type=positive, default=links, help=f"robot links (default {links})")
    p.add_argument("--seed", type=int, default=0, help="controller seed: the MPPI sampling noise (default 0)")
    p.add_argument("--env-seed", type=int, default=0,
                   help="environment seed: random obstacles, port and goal, observed surface points (default 0)")
    p.add_argument("--shape", default="ncedf",
                   help="robot-shape representation of the controller: ncedf, spheres, pointcloud:P, exact "
                        "(default ncedf)")
    p.add_argument("--model", metavar="PATH", type=path_text,
                   help="N-CEDF weights: the robot's links and, for --shape ncedf, its network (default: the "
                        "shipped model)")
    p.add_argument("--scale", metavar="S", help="scale the scene (obstacles, speeds, goal) by S about the base; "
                                                "--goal is unscaled (default 1)")
    p.add_argument("--controller", choices=tuple(PRESETS), default=DEFAULT,
                   help=f"controller preset, listed below (default {DEFAULT})")
    p.add_argument("--samples", type=positive, help="MPPI rollouts (default: the controller's)")
    p.add_argument("--horizon", type=positive, help="MPPI horizon in steps (default: the controller's)")
    p.add_argument("--max-steps", type=positive, help=f"step budget (default {max_steps})")
    p.add_argument("--out", default="recording", type=path_text,
                   help="recording path without suffix (default: recording -> recording.rrd, recording.mcap)")
    p.add_argument("--formats", default=",".join(FORMATS), help="comma-separated subset of rrd,mcap (default rrd,mcap)")
    p.add_argument("--mesh-every", type=positive, default=1, help="record the robot mesh every N steps (default 1)")
    p.add_argument("--overwrite", action="store_true", help="replace existing recordings")
    p.add_argument("--viewer", action="store_true", help="also stream live to a Rerun viewer")
    add_cache_option(p)
    return p


def parse_formats(text: str) -> tuple[str, ...]:
    """``"rrd,mcap"`` -> ("rrd", "mcap"); ValueError naming a bad entry."""
    formats = tuple(f.strip() for f in text.split(",") if f.strip())
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ValueError(f"--formats {text!r}: choose a comma-separated subset of {','.join(FORMATS)}")
    return formats


def base_settings(scenario: str, args: argparse.Namespace, **fields) -> EpisodeSettings:
    """EpisodeSettings from the shared options, plus scenario fields (goal, options).

    A model path is kept absolute, so the recorded settings rerun from any folder; ``--scale`` is
    kept as the shared option ``scale``.
    """
    if args.scale is not None:
        fields["options"] = (*fields.get("options", ()), ("scale", args.scale))
    return EpisodeSettings(
        scenario=scenario, links=args.links, seed=args.seed, env_seed=args.env_seed, shape=args.shape,
        model=str(Path(args.model).resolve()) if args.model else None, controller=args.controller,
        samples=args.samples, horizon=args.horizon, max_steps=args.max_steps, **fields)


def summary(result: EpisodeResult) -> str:
    """Lines describing the outcome, solver time, clearance and the files written."""
    if result.outcome == "success":
        head = f"outcome: success, goal reached at step {result.reach_step}"
    elif result.outcome == "collision" and result.steps == 0:
        head = "outcome: collision at the start: the robot's start pose overlaps an obstacle"
    elif result.outcome == "collision":
        head = f"outcome: collision in step {result.first_collision_step}"
    else:
        head = f"outcome: {result.outcome}"
    lines = [f"{head} ({result.steps} MPPI steps)"]
    if result.steps:
        lines.append(f"solver: {result.solver_ms_mean:.1f} +- {result.solver_ms_std:.1f} ms per MPPI step")
    clearance = f"{result.min_true_distance:.4f} m" if math.isfinite(result.min_true_distance) else "no obstacles"
    lines.append(f"min exact distance: {clearance}; final goal distance {result.final_goal_distance:.3f} m")
    if result.paths:
        lines.append("wrote " + ", ".join(result.paths))
        rrd = [p for p in result.paths if p.endswith(".rrd")]
        lines.append(f"replay: rerun {rrd[0]}" if rrd else f"inspect: python -m recorder.inspect {result.paths[0]}")
    return "\n".join(lines)


def scenario_main(scenario: str, description: str, max_steps: int, argv: list[str] | None) -> int:
    """The whole command of a runner without options of its own."""
    return run_cli(make_parser(scenario, description, max_steps=max_steps), argv,
                   lambda args: base_settings(scenario, args))


def run_cli(parser: argparse.ArgumentParser, argv: list[str] | None,
            make_settings: Callable[[argparse.Namespace], EpisodeSettings]) -> int:
    """Parse, validate, run one recorded episode with a progress bar, print the summary; the exit status."""
    with one_line_warnings():
        return _run(parser, argv, make_settings)


def _run(parser: argparse.ArgumentParser, argv: list[str] | None,
         make_settings: Callable[[argparse.Namespace], EpisodeSettings]) -> int:
    args = parser.parse_args(argv)
    enable_compile_cache(not args.no_cache)
    try:
        with stop_on_signals():
            try:
                settings = make_settings(args)
                formats = parse_formats(args.formats)
                episode = Episode(settings)
                check_writable(output_paths(args.out, formats), args.overwrite)
            except (ValueError, RecorderError) as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 2
            result = episode.run(args.out, formats=formats, overwrite=args.overwrite, mesh_every=args.mesh_every,
                                 viewer=args.viewer, progress=True)
    except Stopped as stop:
        print(f"stopped by {stop}; nothing was written", file=sys.stderr)
        return EXIT_STATUS[stop.signum]
    if result.outcome == "interrupted":
        print(f"interrupted by {result.signal} after {result.steps} MPPI steps; kept them in "
              f"{' and '.join(result.paths)} (outcome 'interrupted')", file=sys.stderr)
        return EXIT_STATUS[signal.Signals[result.signal]]
    print(summary(result))
    return 0
