"""Which dynamic-sphere collisions could any controller have avoided? ``python bench/sphere_oracle.py``.

For each environment of ``scenarios.spheres`` (4 links), the omniscient
planner of ``scenarios.oracle`` (the spheres' whole motion known in advance)
searches for a motion that reaches the goal without touching a sphere, over
the horizons ``--horizons`` (steps, shortest first), and prints the reach step
of the first motion the exact judge passes, or "none found". With ``--runs
FOLDER`` (recordings of ``scenarios.sweep`` / ``reproduce``) it searches only
the environments where a recorded episode collided, and sorts those
collisions into avoidable (a judged motion exists) and not (none found: the
search is local, so this is evidence, not proof). Their count over the
environments is an estimate of the collision rate no controller can go below.

    python bench/sphere_oracle.py --envs 200 --runs runs/table3
    python bench/sphere_oracle.py --envs 200 --goal random --runs runs/table3_random
    python bench/sphere_oracle.py --env0 40 --envs 10

The printed figures, measured, are in ``docs/experiments.md``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from arguments import non_negative, parse_list, positive, runs_folder  # noqa: E402
from ncedf.mppi import MPPIConfig  # noqa: E402
from ncedf.robot import RobotSpec  # noqa: E402
from recorder.cli import EXIT_STATUS, OneLineParser, Stopped, exit_with, stop_on_signals  # noqa: E402
from scenarios.episode import goal_text  # noqa: E402
from scenarios.floor import HORIZONS, LINKS  # noqa: E402
from scenarios.oracle import OracleConfig, plan_reach  # noqa: E402
from scenarios.spheres import TOLERANCE, make_environment  # noqa: E402



def recorded_collisions(folder: str, goal: str, envs: range) -> dict[int, list[str]]:
    """env -> ["shape/controller at step k", ...] of the recorded collided sphere episodes in ``envs``."""
    from recorder.read import load_summaries

    df = load_summaries(folder)
    df = df[(df.scenario == "spheres") & (df["settings.goal"] == goal) & (df.outcome == "collision")
            & (df.links == LINKS)]  # the robot judged here
    out: dict[int, list[str]] = {}
    for _, row in df.iterrows():
        env = int(row.env_seed)
        if env in envs:
            out.setdefault(env, []).append(f"{row['shape']}/{row['controller']} at step "
                                           f"{int(row.first_collision_step)}")
    return out


def main(argv=None) -> int:
    p = OneLineParser(prog="python bench/sphere_oracle.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=positive, default=200, help="environments env0 .. env0 + N - 1 (default 200)")
    p.add_argument("--env0", type=non_negative, default=0, help="first environment (default 0)")
    p.add_argument("--goal", type=goal_text, default="fixed", metavar="GOAL",
                   help="fixed, random or X,Y,Z in m (default fixed)")
    p.add_argument("--horizons", default=tuple(HORIZONS),
                   type=lambda t: tuple(parse_list(t, int, "horizon", above_zero=True)),
                   help=f"horizons to try, steps (default {','.join(map(str, HORIZONS))})")
    p.add_argument("--starts", type=positive, default=OracleConfig.starts,
                   help=f"random starts per horizon (default {OracleConfig.starts})")
    p.add_argument("--runs", type=runs_folder, help="only the environments where these recordings collided")
    args = p.parse_args(argv)
    horizons = args.horizons
    envs = range(args.env0, args.env0 + args.envs)
    collisions = recorded_collisions(args.runs, args.goal, envs) if args.runs else None
    todo = sorted(collisions) if collisions is not None else list(envs)
    spec, config, dt = RobotSpec(LINKS), OracleConfig(starts=args.starts), MPPIConfig.dt

    found, none = {}, []
    start = time.perf_counter()
    status = 0
    try:
        with stop_on_signals():
            for env in tqdm(todo, desc="environments", file=sys.stderr, dynamic_ncols=True):
                world, goal, _ = make_environment(env, spec, args.goal)
                result = plan_reach(world, spec, goal, TOLERANCE, horizons, dt, jax.random.PRNGKey(env), config)
                recorded = "; ".join(collisions[env]) if collisions is not None else ""
                if result.reach_step is None:
                    none.append(env)
                    line = f"env {env}: none found up to {max(horizons)} steps"
                else:
                    found[env] = result.reach_step
                    line = (f"env {env}: reached at step {result.reach_step}, "
                            f"smallest exact distance {result.min_distance:.3f} m")
                tqdm.write(line + (f"  (recorded collision: {recorded})" if recorded else ""), file=sys.stdout)
    except Stopped as stop:
        print(f"interrupted ({stop}): {len(found) + len(none)} of {len(todo)} environments searched; "
              "summary of those follows", file=sys.stderr)
        status = EXIT_STATUS[stop.signum]
    searched = len(found) + len(none)
    what = "collided environments" if collisions is not None else "environments"
    print(f"{args.goal} goal: {searched} {what} searched in {time.perf_counter() - start:.0f} s; "
          f"a judged collision-free motion to the goal found in {len(found)}"
          f"{' ' + str(sorted(found)) if collisions is not None else ''}, "
          f"none found in {len(none)} {none}")
    if status == 0:
        print(f"estimated floor of the collision rate over {args.envs} environments: "
              f"{len(none)} / {args.envs} = {len(none) / args.envs:.3f}"
              + (" (the recorded successes are witnesses for the others)" if collisions is not None else ""))
    return status


if __name__ == "__main__":
    exit_with(main())
