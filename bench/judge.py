"""The exact judge against meshes of 10^2 to 10^6 triangles, old and new: ``python bench/judge.py``.

    python bench/judge.py
    python bench/judge.py --faces 200,100000 --steps 40 --old-limit 2000

Per face count, a closed, non-convex mesh (a torus, major radius 2 m, minor 0.6 m) is placed
so that its surface passes 5 cm from the middle of a 7-link robot, and the robot takes
``--steps`` control steps of a smooth random walk in arc lengths (sub-steps as the episodes
judge them: 2 cm of motion between checks; about 3 per step). Printed per face count: judged
steps per second with the new judge (``scenarios.judge``) and with the judge of ``--old``
(the git revision before it, loaded from history: it is only run up to ``--old-limit`` faces,
where it takes seconds per step), their ratio (each the best of ``--repeats`` passes over the walk,
after a first that compiles every batch size and builds the BVH), the closest judged distance and the largest
certificate; for the new judge, where its time goes (BVH queries, robot geometry, the rest).
Then the paper's cluttered scene (boxes and spheres, 7 links) judged by both, and the time to
draw the observation of the largest mesh.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
import types

import jax
import numpy as np
import trimesh

from arguments import non_negative, parse_list, positive
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths
from recorder.cli import OneLineParser, exit_with
from rows import print_rows
from scenarios import cluttered, judge, mesh_distance, mesh_index
from scenarios.observe import make_observer
from scenarios.world import MeshObstacle, World

OLD = "7cf037d"
LINKS = 7
GAP = 0.05  # m between the mesh and the robot's middle at the start


def old_judge(revision: str) -> types.ModuleType:
    """The module ``scenarios/world.py`` of ``revision``, loaded from git history."""
    source = subprocess.run(["git", "show", f"{revision}:scenarios/world.py"], capture_output=True, text=True,
                            check=True).stdout
    module = types.ModuleType("old_world")
    module.__dict__["__name__"] = "old_world"
    sys.modules["old_world"] = module
    exec(compile(source, f"{revision}:scenarios/world.py", "exec"), module.__dict__)
    return module


def torus(faces: int) -> trimesh.Trimesh:
    """A torus of about ``faces`` triangles (2 per quad, 5 major sections per minor one)."""
    minor = max(3, int(round(np.sqrt(faces / 10))))
    return trimesh.creation.torus(2.0, 0.6, major_sections=max(3, faces // (2 * minor)), minor_sections=minor)


def walk(spec: RobotSpec, steps: int, seed: int) -> np.ndarray:
    """A smooth random walk of ``steps + 1`` states (arc lengths within the limits)."""
    rng = np.random.default_rng(seed)
    start = np.asarray(sample_arc_lengths(jax.random.PRNGKey(seed), spec, (1, spec.n_links)), np.float64)[0]
    velocity = np.zeros_like(start)
    states = [start]
    for _ in range(steps):
        velocity = 0.8 * velocity + 0.2 * rng.normal(0.0, 0.0005, start.shape)
        states.append(np.clip(states[-1] + velocity, spec.l_min, spec.l_max))
    return np.stack(states)


def placed(mesh: trimesh.Trimesh, spec: RobotSpec, arc: np.ndarray) -> MeshObstacle:
    """``mesh`` moved so that its surface is GAP from the robot's middle, beside it."""
    frames = np.asarray(forward_kinematics(arc, spec))
    middle = frames[spec.n_links // 2, :3, 3]
    side = np.cross(frames[spec.n_links // 2, :3, 2], [0.0, 0.0, 1.0]) + [1e-3, 0.0, 0.0]
    side /= np.linalg.norm(side)
    # the torus's outer rim (2.6 m from its centre in its plane) faces the robot's middle
    centre = middle + side * (spec.radius + GAP + 2.6)
    return MeshObstacle(mesh.vertices + centre, mesh.faces, f"torus {len(mesh.faces)}")


def run_judge(step, world, spec: RobotSpec, states: np.ndarray, repeats: int = 1, dt: float = 0.05):
    """Judged steps per second (the best of ``repeats`` passes), the closest distance and the largest
    certificate."""
    elapsed = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        found = [step(world, spec, a, b, i * dt, dt) for i, (a, b) in enumerate(zip(states[:-1], states[1:]))]
        elapsed = min(elapsed, time.perf_counter() - start)
    return (len(found) / elapsed, min(j.min_distance for j in found),
            max(getattr(j, "certificate", np.nan) for j in found), np.mean([j.substeps for j in found]))


class Clock:
    """Time spent in the new judge's BVH queries and robot geometry, while in a ``with`` block."""

    PARTS = {"bvh": (mesh_index.MeshIndex, "distance"), "geometry": (mesh_distance, "cell_points")}

    def __enter__(self):
        self.spent = dict.fromkeys(self.PARTS, 0.0)
        self.saved = {part: getattr(owner, name) for part, (owner, name) in self.PARTS.items()}
        for part, (owner, name) in self.PARTS.items():
            setattr(owner, name, self._timed(self.saved[part], part))
        return self

    def _timed(self, inner, part: str):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.spent[part] += time.perf_counter() - start
        return timed

    def __exit__(self, *exc):
        for part, (owner, name) in self.PARTS.items():
            setattr(owner, name, self.saved[part])


def mesh_rows(args, old) -> object:
    """One row per face count (a generator, so that print_rows prints each when measured)."""
    spec = RobotSpec(LINKS)
    states = walk(spec, args.steps, args.seed)
    yield "faces    new steps/s  (bvh / geometry / rest)   old steps/s   new/old  closest m  certificate m  substeps"
    for faces in args.faces:
        mesh = placed(torus(faces), spec, states[0])
        world = World(meshes=(mesh,))
        run_judge(judge.judge_step, world, spec, states)  # builds the BVH, compiles every batch size once
        start = time.perf_counter()
        with Clock() as clock:
            rate, closest, certificate, substeps = run_judge(judge.judge_step, world, spec, states, args.repeats)
        total = time.perf_counter() - start
        shares = [clock.spent[k] / total for k in ("bvh", "geometry")]
        old_text, ratio = "-", "-"
        if old is not None and len(mesh.faces) <= args.old_limit:
            old_world = old.World(meshes=(old.MeshObstacle(mesh.vertices, mesh.faces),))
            old_steps = states[: args.old_steps + 1]
            old.judge_step(old_world, spec, old_steps[0], old_steps[1], 0.0, 0.05)
            old_rate = run_judge(old.judge_step, old_world, spec, old_steps, args.repeats)[0]
            old_text, ratio = f"{old_rate:11.3f}", f"{rate / old_rate:7.0f}x"
        yield (f"{len(mesh.faces):>8}  {rate:10.1f}   ({shares[0]:4.0%} / {shares[1]:4.0%} / "
               f"{1 - sum(shares):4.0%})      {old_text:>11}   {ratio:>7}  {closest:9.4f}  {certificate:13.5f}  "
               f"{substeps:8.1f}")


def paper_rows(args, old):
    """The paper's cluttered scene, judged by both, and the observation of the largest mesh."""
    spec = RobotSpec(LINKS)
    states = walk(spec, args.steps, args.seed + 1)
    world = cluttered.make_world()
    run_judge(judge.judge_step, world, spec, states)
    if old is not None:
        old_world = old.World(spheres=tuple(old.MovingSphere(s.centre, s.radius, s.velocity, s.half_period)
                                            for s in world.spheres),
                              boxes=tuple(old.Box(b.centre, b.size) for b in world.boxes))
        run_judge(old.judge_step, old_world, spec, states)
    rates = {"new": [], "old": []}
    for _ in range(args.repeats):  # interleaved, so that both see the same load
        rates["new"].append(run_judge(judge.judge_step, world, spec, states)[0])
        if old is not None:
            rates["old"].append(run_judge(old.judge_step, old_world, spec, states)[0])
    line = f"cluttered (boxes, spheres): new {max(rates['new']):.1f} steps/s"
    if old is not None:
        line += f", old {max(rates['old']):.1f} steps/s, new/old {max(rates['new']) / max(rates['old']):.2f}"
    yield line
    mesh = placed(torus(max(args.faces)), spec, states[0])
    for density in (4.0, 400.0):
        start = time.perf_counter()
        observer = make_observer(World(meshes=(mesh,), density=density), 0)
        yield (f"observation of {len(mesh.faces)} faces at {density:g} points/m^2: {observer.n_points} points "
               f"in {time.perf_counter() - start:.2f} s")


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--faces", type=lambda t: parse_list(t, int, "face count", above_zero=True),
                   default=[100, 1000, 10000, 100000, 1000000], help="mesh sizes (default 100,...,1000000)")
    p.add_argument("--steps", type=positive, default=40, help="judged control steps per mesh (default 40)")
    p.add_argument("--old-steps", type=positive, default=3, help="steps judged by the old judge (default 3)")
    p.add_argument("--old-limit", type=positive, default=2000, help="largest mesh the old judge is run on")
    p.add_argument("--old", default=OLD, help=f"git revision of the old judge (default {OLD}; 'none' skips it)")
    p.add_argument("--seed", type=non_negative, default=0, help="random walk seed (default 0)")
    p.add_argument("--repeats", type=positive, default=3, help="timed passes, the best kept (default 3)")
    args = p.parse_args(argv)
    if args.old != "none" and subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{args.old}^{{commit}}"],
                                             capture_output=True).returncode != 0:
        p.error(f"--old: not a git revision here: {args.old!r} (or 'none')")
    old = None if args.old == "none" else old_judge(args.old)
    status = print_rows(mesh_rows(args, old), lambda line: [line])
    return status or print_rows(paper_rows(args, old), lambda line: [line])


if __name__ == "__main__":
    exit_with(main())
