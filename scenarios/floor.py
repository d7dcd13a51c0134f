"""What no controller can do among the dynamic spheres: ``python -m scenarios.floor RUNS``.

For every environment (link count, goal kind, environment seed) of the sphere episodes recorded under
RUNS (the paper's links, the scene as built) where no recorded episode reached the goal, two
verdicts, recorded as one run of scenario ``floor`` (``RUNS/floor/floor_<goal>_env<N>.mcap`` for
Table III's 4 links, ``..._env<N>_L<links>.mcap`` for others):

* **certain**: every configuration contains the first link's base disk (arc lengths move the
  body, never its base), so a sphere that overlaps that disk in step k collides with every
  controller that has not reached the goal by step k - 1; certain when no motion within the rate
  bounds brings the end effector within the goal's tolerance by then
  (:func:`scenarios.oracle.closest_approach`);
* **the oracle** (:func:`scenarios.oracle.plan_reach`, the spheres' motion known in advance): a
  motion to the goal that the exact judge passes (outcome ``success``, its states recorded for
  replay) or none found (outcome ``collision``: evidence that no controller avoids it, not proof).

Where a recorded episode reached the goal it is itself the witness, so nothing is searched.
Table III (``analysis``) reads the verdicts: the certain floor, the environments the oracle
cannot solve, and the avoidable collisions (those in environments some motion solves).
Resumable: a verdict already recorded and closed is kept.
"""

from __future__ import annotations

import dataclasses
import re
import sys
import time
from pathlib import Path

import jax
import numpy as np

from analysis.paper import TABLE3_LINKS
from ncedf.geometry import robot_mesh_arrays
from ncedf.mppi import MPPIConfig
from ncedf.robot import RobotSpec, forward_kinematics
from recorder import Recorder, RecordingInterrupted
from recorder.cli import EXIT_STATUS, OneLineParser, Stopped, exit_with, path_text, positive, stop_on_signals
from scenarios.episode import obstacle_shapes
from scenarios.oracle import OracleConfig, closest_approach, plan_reach
from scenarios.spheres import MAX_STEPS, TOLERANCE, make_environment
from scenarios.world import World

#: Scenario name of a verdict's recording.
SCENARIO = "floor"
#: The robot of the paper's sphere scene (Table III's), whose verdicts' names carry no link count.
LINKS = TABLE3_LINKS
#: Control step of the scenarios, s (every preset keeps the default).
STEP_DT = MPPIConfig.dt
#: Horizons the oracle tries, steps, shortest first.
HORIZONS = (8, 10, 12, 15, 20, 25, 30, 40)
#: Time sampling of the base-disk test, s (an overlap shorter than this may be missed: a lower bound).
BASE_DT = 0.005
#: Starts of each closest-approach search.
APPROACH_STARTS = 64


def disk_gap(centres: np.ndarray, radii: np.ndarray, disk_radius: float) -> np.ndarray:
    """Distance from each sphere to the base disk (radius ``disk_radius`` at the origin in the plane
    z = 0; negative = overlap), m.  centres: (..., S, 3) m.  radii: (S,) m."""
    rho = np.linalg.norm(centres[..., :2], axis=-1)
    return np.hypot(np.maximum(rho - disk_radius, 0.0), centres[..., 2]) - radii


def first_base_hit(world: World, spec: RobotSpec, horizon: float, dt: float = BASE_DT) -> float | None:
    """First sampled time in [0, horizon] at which a sphere overlaps the base disk, s (None if never)."""
    times = np.arange(0.0, horizon + 0.5 * dt, dt)
    centres = world.sphere_track(times)  # (T, S, 3)
    radii = np.array([s.radius for s in world.spheres])
    hit = np.any(disk_gap(centres, radii, spec.radius) < 0.0, axis=1)
    return float(times[np.argmax(hit)]) if hit.any() else None


def hit_step(hit_time: float) -> int:
    """The control step whose interval ((k - 1) dt, k dt] holds a sampled hit time (which lies at or
    after the overlap's start, so the deadline ``k - 1`` is never too early)."""
    return int(np.ceil(hit_time / STEP_DT - 1e-9))


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


@dataclasses.dataclass(frozen=True)
class Verdict:
    """What any controller can do in one environment: ``base_hit_step`` (None: no sphere crosses the
    base disk within the step budget), ``certain`` (a collision whatever the controller), and the
    oracle's motion (``result``, ``scenarios.oracle.OracleResult``)."""

    base_hit_step: int | None
    certain: bool
    result: object


def judge_environment(world: World, goal: np.ndarray, spec: RobotSpec, reach: Reach, config: OracleConfig,
                      key) -> Verdict:
    """The :class:`Verdict` of one environment (the oracle is not searched where the hit is certain)."""
    hit = first_base_hit(world, spec, MAX_STEPS * STEP_DT)
    step = None if hit is None else hit_step(hit)
    certain = step is not None and not reach.within(goal, step - 1)[0]
    result = None if certain else plan_reach(world, spec, goal, TOLERANCE, HORIZONS, STEP_DT, key, config)
    return Verdict(step, certain, result)


def verdict_stem(out: Path, goal: str, env: int, links: int = LINKS) -> Path:
    """``out/floor_<goal>_env<env>`` (``_L<links>`` appended for another link count than Table III's),
    the goal's text made file-name safe and kept apart ("-4.5,0,1" -> "m4p5_0_1")."""
    safe = re.sub(r"[^A-Za-z0-9_]", "", goal.replace("-", "m").replace(".", "p").replace(",", "_"))
    return out / f"{SCENARIO}_{safe}_env{env}{'' if links == LINKS else f'_L{links}'}"


def record_verdict(stem: Path, goal_kind: str, env: int, world: World, goal: np.ndarray, spec: RobotSpec,
                   verdict: Verdict) -> None:
    """One recording of the verdict: its facts in the run metadata, the oracle's motion (if any) as
    steps, outcome ``success`` (a judged motion to the goal) or ``collision`` (none found, or certain)."""
    meta = {"scenario": SCENARIO, "links": spec.n_links, "env_seed": env, "settings": {"goal": goal_kind},
            "base_hit_step": verdict.base_hit_step, "certain": verdict.certain, "horizons": list(HORIZONS)}
    result = verdict.result
    found = result is not None and result.reach_step is not None
    with Recorder(stem, meta, formats=("mcap",), overwrite=True, goal_tolerance=TOLERANCE) as rec:
        for k, arc in enumerate(result.arcs if found else ()):
            t = k * STEP_DT
            frames = np.asarray(forward_kinematics(arc, spec))
            vertices, faces = robot_mesh_arrays(arc, spec)
            rec.log_step(k, t, metrics={"goal_distance": float(np.linalg.norm(frames[-1, :3, 3] - goal))},
                         mesh_vertices=vertices, mesh_triangles=faces, obstacle_shapes=obstacle_shapes(world, t),
                         goal=goal)
        rec.finish({"outcome": "success", "steps": result.reach_step, "reach_step": result.reach_step,
                    "min_true_distance": result.min_distance} if found else {"outcome": "collision", "steps": 0})


def open_environments(folder: Path) -> tuple[list[tuple[int, str, int]], int]:
    """(links, goal kind, environment seed) of the sphere episodes under ``folder`` of the paper's links
    (:func:`analysis.load.sphere_episodes`) where none reached the goal, sorted; and the number of
    sphere episodes of other robots (links of another size, a scaled scene), which it does not judge.
    Raises ValueError where ``folder`` holds no sphere episode at all."""
    from analysis.load import load, sphere_episodes

    recordings = load(folder)
    spheres = recordings.scenario("spheres")
    if spheres.empty:
        raise ValueError(f"no dynamic-sphere episodes in {folder} (python -m scenarios.spheres or a sweep of them "
                         "records them)")
    runs = sphere_episodes(recordings)
    others = len(spheres) - len(runs)
    if runs.empty:
        return [], others
    keys = ["links", "goal_kind", "env_seed"]
    solved = runs.groupby(keys)["outcome"].apply(lambda o: bool((o == "success").any()))
    return sorted((int(links), str(goal), int(env)) for (links, goal, env), ok in solved.items() if not ok), others


def describe(links: int, goal_kind: str, env: int, verdict: Verdict) -> str:
    """One line per verdict, as the command prints it."""
    where = f"{links} links, {goal_kind} goal, env {env}: "
    if verdict.certain:
        return where + f"certain collision (a sphere on the base disk in step {verdict.base_hit_step})"
    result = verdict.result
    if result.reach_step is None:
        return where + f"no judged motion found up to {max(HORIZONS)} steps"
    return where + f"a judged motion reaches the goal at step {result.reach_step} (smallest distance " \
                   f"{result.min_distance:.3f} m)"


def parse_args(argv=None):
    p = OneLineParser(prog="python -m scenarios.floor", description=__doc__.split("\n\n")[0],
                      epilog="Exit status: 0 done, 2 bad arguments or no sphere episodes, 130/143 interrupted (run it "
                             "again to finish).")
    p.add_argument("runs", type=path_text, help="folder of sphere recordings (a sweep's or the reproduction's)")
    p.add_argument("--starts", type=positive, default=OracleConfig.starts,
                   help=f"random starts of each oracle search (default {OracleConfig.starts})")
    args = p.parse_args(argv)
    if not Path(args.runs).is_dir():
        p.error(f"{args.runs} is not a folder of recordings")
    return args


def run_floor(folder: Path, starts: int = OracleConfig.starts) -> int:
    """Record the verdicts of ``folder``'s open environments in ``folder/floor`` (resumes); the exit
    status: 0 done, 2 no sphere episodes there, 130 / 143 stopped by SIGINT / SIGTERM (one line says what was kept)."""
    from tqdm import tqdm

    from scenarios.sweep import read_complete

    try:
        todo, others = open_environments(folder)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out, config, reaches = folder / SCENARIO, OracleConfig(starts=starts), {}
    start, done = time.perf_counter(), 0
    print(f"floor: {len(todo)} environments of {folder} where no recorded episode reached the goal", file=sys.stderr)
    if others:
        print(f"floor: {others} sphere episodes of other robots left out (it judges the paper's links, the scene "
              "as built)", file=sys.stderr)
    try:
        with stop_on_signals():
            for links, goal_kind, env in tqdm(todo, desc="floor", unit="env", file=sys.stderr, dynamic_ncols=True):
                stem = verdict_stem(out, goal_kind, env, links)
                if read_complete(stem, ("mcap",)) is None:
                    spec = RobotSpec(links)
                    if links not in reaches:  # its searches' memory serves every environment of the robot
                        reaches[links] = Reach(spec, OracleConfig(starts=APPROACH_STARTS))
                    reach = reaches[links]
                    world, goal, _ = make_environment(env, spec, goal_kind)
                    verdict = judge_environment(world, goal, spec, reach, config, jax.random.PRNGKey(env))
                    record_verdict(stem, goal_kind, env, world, goal, spec, verdict)
                    tqdm.write(describe(links, goal_kind, env, verdict), file=sys.stdout)
                done += 1
    except (Stopped, RecordingInterrupted) as stop:
        print(f"interrupted: {done} of {len(todo)} verdicts recorded in {out}; the same command finishes "
              "the rest", file=sys.stderr)
        return EXIT_STATUS[stop.signum]
    print(f"floor: {done} verdicts in {out} ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_floor(Path(args.runs), args.starts)


if __name__ == "__main__":
    exit_with(main())
