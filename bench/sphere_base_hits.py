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

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from arguments import positive  # noqa: E402
from ncedf.mppi import MPPIConfig  # noqa: E402
from ncedf.robot import RobotSpec  # noqa: E402
from recorder.cli import OneLineParser, exit_with  # noqa: E402
from scenarios.episode import goal_text  # noqa: E402
from scenarios.oracle import OracleConfig, closest_approach  # noqa: E402
from scenarios.spheres import MAX_STEPS, TOLERANCE, make_environment  # noqa: E402
from scenarios.world import World  # noqa: E402

#: Control step of the scenarios, s (every preset keeps the default).
STEP_DT = MPPIConfig.dt


def disk_gap(centres: np.ndarray, radii: np.ndarray, disk_radius: float) -> np.ndarray:
    """Distance from each sphere to the base disk (negative = overlap), m.

    Args:
      centres: (..., S, 3) m.  radii: (S,) m.
    """
    rho = np.linalg.norm(centres[..., :2], axis=-1)
    return np.hypot(np.maximum(rho - disk_radius, 0.0), centres[..., 2]) - radii


def first_base_hit(world: World, spec: RobotSpec, horizon: float, dt: float) -> float | None:
    """First sampled time in [0, horizon] at which a sphere overlaps the base disk, s (None if never)."""
    times = np.arange(0.0, horizon + 0.5 * dt, dt)
    centres = world.sphere_track(times)  # (T, S, 3)
    radii = np.array([s.radius for s in world.spheres])
    hit = np.any(disk_gap(centres, radii, spec.radius) < 0.0, axis=1)
    return float(times[np.argmax(hit)]) if hit.any() else None


class Reach:
    """Whether the goal can be reached within a number of steps, per goal, from as few searches as the
    nesting of the reachable sets allows (reachable within k implies within every k' > k)."""

    def __init__(self, spec: RobotSpec, config: OracleConfig):
        self.spec, self.config = spec, config
        self.reached: dict[tuple, int] = {}  # goal -> smallest steps found to reach it
        self.missed: dict[tuple, tuple[int, float]] = {}  # goal -> (largest steps found short, closest, m)

    def within(self, goal, steps: int) -> tuple[bool, int, float]:
        """(reachable within ``steps`` steps, the steps searched, the closest approach found then, m).

        A search for more steps that fell short answers for fewer (its closest approach is a lower bound
        for them); one that reached answers for more (nan)."""
        key = tuple(float(g) for g in goal)
        if steps < 1:
            return False, 0, np.nan
        if steps <= self.missed.get(key, (0, np.nan))[0]:
            return False, *self.missed[key]
        if steps >= self.reached.get(key, np.inf):
            return True, self.reached[key], np.nan
        closest = closest_approach(self.spec, goal, steps, STEP_DT, jax.random.PRNGKey(steps), self.config)
        if closest <= TOLERANCE:  # searched only below a known reach, so this is the smallest yet
            self.reached[key] = steps
        else:
            self.missed[key] = (steps, closest)
        return closest <= TOLERANCE, steps, closest


def main(argv=None) -> int:
    p = OneLineParser(prog="python bench/sphere_base_hits.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=positive, default=200, help="environments 0..N-1 (default 200)")
    p.add_argument("--goal", type=goal_text, default="fixed", metavar="GOAL",
                   help="fixed, random or X,Y,Z in m (default fixed)")
    p.add_argument("--dt", type=float, default=0.005, help="time sampling, s (default 0.005)")
    p.add_argument("--runs", help="folder of sphere recordings to compare with")
    p.add_argument("--starts", type=positive, default=64, help="starts of each closest-approach search (default 64)")
    args = p.parse_args(argv)
    if args.dt <= 0:
        p.error(f"--dt must be > 0, got {args.dt}")
    spec = RobotSpec(4)
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
        # the sampled time is at or after the overlap's start, so this deadline is never too early
        deadline = int(np.ceil(t / STEP_DT - 1e-9)) - 1
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
        df = df[(df.scenario == "spheres") & (df["settings.goal"] == args.goal) & (df.env_seed < args.envs)]
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
    exit_with(main())
