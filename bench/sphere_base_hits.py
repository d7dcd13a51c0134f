"""Dynamic-sphere environments whose collision no controller can avoid: ``python bench/sphere_base_hits.py``.

Every configuration of the robot contains the base disk of its first link
(radius r, at the origin, in the plane z = 0): arc lengths move the body, never
its base. A sphere that overlaps that disk collides with the robot whatever the
controller does, unless the episode has already ended. Per environment and goal
kind of ``scenarios.spheres`` this prints the first time (and control step) at
which a sphere overlaps the base disk, sampled every ``--dt`` seconds over the
episode's step budget; a sampled overlap is a real one (a lower bound on the
unavoidable collisions: overlaps shorter than ``--dt`` are missed).

Such an overlap is certain to end the episode in a collision when no motion
reaches the goal before it: with the hit in step k (at a time in ((k - 1) dt,
k dt]), the goal must be reached by step k - 1. For each hit this asks
``scenarios.oracle.closest_approach`` for the closest the end effector comes
within k - 1 steps, over every rate sequence of the control set (the release's,
which the oracle searches: two free rates per link within +-0.3 m/s, the
third minus their sum), and counts the environment as certain when that is
farther than the goal tolerance. That is a numerical minimum: the fixed goal
within 7 steps, 256 starts, came to 0.447 m at best and 0.453 m at the median,
and a one-off search over constant rates (which reach every state reachable in
those steps: the control set is convex) from 4096 starts to 0.441 m; so
"certain" holds up to those millimetres, far from the 0.2 m tolerance here.

Measured over 1000 environments per goal kind: ``docs/experiments.md``.

With ``--runs FOLDER`` (recordings of ``scenarios.sweep``/``reproduce``), it also
lists the environments where the recorded episodes collided, the earliest
reach step of any successful episode there, and how many collisions fall in
environments whose base disk is hit before that step, where no controller
reaching the goal at that pace can avoid them.

    python bench/sphere_base_hits.py --envs 200 --runs runs/table3
    python bench/sphere_base_hits.py --envs 200 --goal random --runs runs/table3_random
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from arguments import positive, positive_float, runs_folder  # noqa: E402
from ncedf.robot import RobotSpec  # noqa: E402
from recorder.cli import OneLineParser, exit_with, stoppable  # noqa: E402
from scenarios.episode import goal_text  # noqa: E402
from scenarios.floor import BASE_DT, LINKS, STEP_DT, Reach, first_base_hit, hit_step  # noqa: E402
from scenarios.oracle import OracleConfig  # noqa: E402
from scenarios.spheres import MAX_STEPS, TOLERANCE, make_environment  # noqa: E402


def main(argv=None) -> int:
    p = OneLineParser(prog="python bench/sphere_base_hits.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=positive, default=200, help="environments 0..N-1 (default 200)")
    p.add_argument("--goal", type=goal_text, default="fixed", metavar="GOAL",
                   help="fixed, random or X,Y,Z in m (default fixed)")
    p.add_argument("--dt", type=positive_float, default=BASE_DT, help=f"time sampling, s (default {BASE_DT})")
    p.add_argument("--runs", type=runs_folder, help="folder of sphere recordings to compare with")
    p.add_argument("--starts", type=positive, default=64, help="starts of each closest-approach search (default 64)")
    args = p.parse_args(argv)
    spec = RobotSpec(LINKS)
    hits, goals = {}, {}
    for env in range(args.envs):
        world, goals[env], _ = make_environment(env, spec, args.goal)
        t = first_base_hit(world, spec, MAX_STEPS * STEP_DT, args.dt)
        if t is not None:
            hits[env] = t
    print(f"{args.goal} goal: {len(hits)} of {args.envs} environments have a sphere through the base disk:")
    print("  " + ", ".join(f"env {e} at {t:.3f} s (step {t / STEP_DT:.1f})" for e, t in hits.items()))
    reach, certain = Reach(spec, OracleConfig(starts=args.starts)), []
    for env, t in hits.items():
        deadline = hit_step(t) - 1
        reachable, searched, closest = reach.within(goals[env], deadline)
        if not reachable:
            certain.append(env)
            print(f"  env {env}: hit in step {deadline + 1}; " + (
                  f"within {searched} steps (>= {deadline}) the end effector comes no closer than {closest:.3f} m "
                  f"to the goal (tolerance {TOLERANCE} m)" if searched else "before any step ends"), flush=True)
    print(f"certain collisions (no motion reaches the goal before the hit): {len(certain)} of {args.envs} "
          f"({len(certain) / args.envs:.3f}) {certain}")
    if args.runs:
        from recorder.read import load_summaries

        df = load_summaries(args.runs)
        df = df[(df.scenario == "spheres") & (df["settings.goal"] == args.goal) & (df.env_seed < args.envs)
                & (df.links == LINKS)]  # the robot judged here
        for (shape, controller), g in df.groupby(["shape", "controller"]):
            fastest = g.loc[g.outcome == "success", "reach_step"].min()
            coll = g[g.outcome == "collision"]
            early = [int(e) for e in coll.env_seed if e in hits and hits[e] / STEP_DT < fastest]
            late = [int(e) for e in coll.env_seed if e in hits and e not in early]
            print(f"{shape} / {controller}: {len(g)} episodes, {len(coll)} collisions; earliest reach step "
                  f"{fastest:.0f}; collisions where the base disk is hit before it: {len(early)} {early}; "
                  f"hit later: {len(late)} {late}; other: "
                  f"{sorted(int(e) for e in coll.env_seed if e not in hits)}")
        unavoidable = sorted(e for e, t in hits.items() if t / STEP_DT < df.loc[df.outcome == 'success',
                                                                                'reach_step'].min())
        print(f"environments no controller reaching the goal at the recorded pace can keep collision-free: "
              f"{len(unavoidable)} of {args.envs} ({len(unavoidable) / args.envs:.3f}) {unavoidable}")
    return 0


if __name__ == "__main__":
    exit_with(stoppable(main))
