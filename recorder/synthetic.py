"""Synthetic, deterministic robot-like runs for tests, benchmarks and trying the viewers.

A chain of M bending tubes (the "robot", links of 2 m and radius 0.2 m like the project's robots)
bending in one plane, two moving spheres and a box, the observed points on their surfaces, a goal
(a position, or with `--pose-goal` a pose approached along +x) with its tolerance, a planned path
from the end effector to the goal, and each link's clearance (distance of its tube to the nearest
obstacle: centre-line samples against the exact sphere and box distances, minus the tube radius).
Every value is a function of (seed, step) alone.

    python -m recorder.synthetic OUT [--steps 20] [--links 4] [--pose-goal] [--viewer [URL]]
                                     [--step-delay 0] [--print-steps]

writes OUT.rrd and OUT.mcap (flush/mesh/overwrite options as in `Recorder`); `--viewer` also
streams the run to a Rerun Viewer (see `recorder.viewer`); with `--print-steps` it prints
`step K` after each recorded step (used by the interruption tests).
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from recorder.errors import RecorderError, RecordingInterrupted
from recorder.viewer import check_url

LINK_LENGTH = 2.0  # m
TUBE_RADIUS = 0.2  # m
GOAL_TOLERANCE = 0.4  # m
SAFETY_MARGIN = 0.05  # m
#: A pose goal's rotation: its z axis (the approach axis) along world +x (a rotation of 90 degrees about y).
APPROACH_X = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


def tube_triangles(links: int, rings: int, ring_points: int) -> np.ndarray:
    """Triangle indices (F, 3) of `links` tubes of `rings` x `ring_points` vertices (side walls only)."""
    ring = np.arange(ring_points)
    a = ring + ring_points * np.arange(rings - 1)[:, None]  # (rings - 1, ring_points): vertex a of each quad
    b = (ring + 1) % ring_points + ring_points * np.arange(rings - 1)[:, None]
    c, d = a + ring_points, b + ring_points
    quads = np.stack([np.stack([a, b, d], -1), np.stack([a, d, c], -1)], axis=2).reshape(-1, 3)  # (a,b,d),(a,d,c)
    offsets = rings * ring_points * np.arange(links)
    return (quads[None] + offsets[:, None, None]).reshape(-1, 3).astype(np.uint32)


def tube_vertices(backbone: np.ndarray, normals: np.ndarray, binormals: np.ndarray, ring_points: int,
                  radius: float = TUBE_RADIUS) -> np.ndarray:
    """Vertices (M * K * ring_points, 3) of tubes around polylines (M, K, 3); rings span normals x binormals."""
    angles = np.linspace(0.0, 2 * np.pi, ring_points, endpoint=False)
    ring = radius * (np.cos(angles)[:, None, None, None] * normals + np.sin(angles)[:, None, None, None] * binormals)
    return (backbone[None] + ring).transpose(1, 2, 0, 3).reshape(-1, 3)


def planar_backbone(theta: np.ndarray, phi: float, rings: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre lines (M, rings, 3) of links bending by `theta` (M,) rad in the plane at angle `phi` from x,
    with the unit normals and binormals (M, rings, 3) of their cross sections."""
    m = theta.shape[0]
    s = np.linspace(0.0, 1.0, rings)
    bend = np.concatenate([[0.0], np.cumsum(theta)[:-1]])[:, None] + theta[:, None] * s  # (M, rings) rad
    in_plane = np.array([np.cos(phi), np.sin(phi), 0.0])
    tangent = np.sin(bend)[..., None] * in_plane + np.cos(bend)[..., None] * np.array([0.0, 0.0, 1.0])
    ds = np.full((m, rings), LINK_LENGTH / (rings - 1))
    ds[:, 0] = 0.0  # a link's first sample is the previous link's last
    backbone = np.cumsum((tangent * ds[..., None]).reshape(-1, 3), axis=0).reshape(m, rings, 3)
    binormal = np.broadcast_to(np.array([-np.sin(phi), np.cos(phi), 0.0]), tangent.shape)
    return backbone, np.cross(binormal, tangent), binormal


def link_clearance(backbone: np.ndarray, shapes: dict) -> np.ndarray:
    """(M,) distance of each tube to the nearest sphere or box (negative inside), from its centre-line samples."""
    p = backbone[:, :, None, :]
    spheres, boxes = shapes["spheres"], shapes["boxes"]
    to_spheres = np.linalg.norm(p - spheres["centers"], axis=-1) - spheres["radii"]  # (M, K, S)
    q = np.abs(p - boxes["centers"]) - boxes["sizes"] / 2  # (M, K, B, 3)
    to_boxes = np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
    return np.minimum(to_spheres.min(axis=(1, 2)), to_boxes.min(axis=(1, 2))) - TUBE_RADIUS


def surface_points(shapes: dict, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points (n, 3) uniformly on the spheres' surfaces, shared between them in turn."""
    centers, radii = shapes["spheres"]["centers"], shapes["spheres"]["radii"]
    which = np.arange(n) % centers.shape[0]
    directions = rng.standard_normal((n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return centers[which] + radii[which, None] * directions


class SyntheticRun:
    """Deterministic step data for a robot of `links` links (mesh of links x rings x ring_points vertices)."""

    def __init__(self, links: int = 4, seed: int = 0, rings: int = 30, ring_points: int = 32,
                 n_points: int = 500, horizon: int = 20, pose_goal: bool = False):
        self.links, self.seed, self.rings, self.ring_points = links, seed, rings, ring_points
        self.n_points, self.horizon, self.pose_goal = n_points, horizon, pose_goal
        self.goal_tolerance, self.safety_margin = GOAL_TOLERANCE, SAFETY_MARGIN
        self.triangles = tube_triangles(links, rings, ring_points)
        self.meta = {"scenario": "synthetic", "links": links, "seed": seed, "shape": "exact",
                     "mppi": {"horizon": horizon, "samples": 64}, "dt": 0.05}

    def step(self, k: int) -> dict:
        """Keyword arguments of `Recorder.log_step` for step k (everything but step and sim_time)."""
        rng = np.random.default_rng([self.seed, k])
        m, height = self.links, self.links * LINK_LENGTH
        theta = 0.25 + 0.15 * np.sin(0.1 * k + np.arange(m))
        phi = 0.2 * np.sin(0.05 * k)
        backbone, normals, binormals = planar_backbone(theta, phi, self.rings)
        ee = backbone[-1, -1]
        goal_position = np.array([0.45, -0.35, 0.55]) * height
        goal = goal_position
        if self.pose_goal:
            goal = np.eye(4)
            goal[:3, :3], goal[:3, 3] = APPROACH_X, goal_position
        shapes = {"spheres": {"centers": np.array([[0.3 * height, 0.4 * np.sin(0.1 * k) - 0.2, 0.4 * height],
                                                   [-0.25 * height, 0.25 * height, 0.7 * height]]),
                              "radii": np.array([0.75, 0.8])},
                  "boxes": {"centers": np.array([[0.3 * height, -0.35 * height, 0.15 * height]]),
                            "sizes": np.array([[1.0, 1.5, 0.3 * height]])}}
        clearance = link_clearance(backbone, shapes)
        t = np.linspace(0.0, 1.0, self.horizon + 1)[:, None]
        plan = (1 - t) * ee + t * goal_position + np.sin(np.pi * t) * np.array([0.0, 0.0, 0.1 * height])
        return {
            "mesh_vertices": tube_vertices(backbone, normals, binormals, self.ring_points),
            "mesh_triangles": self.triangles,
            "backbone": backbone,
            "obstacle_points": surface_points(shapes, self.n_points, rng),
            "obstacle_shapes": shapes,
            "goal": goal,
            "plan": plan,
            "state": {"arc_lengths": LINK_LENGTH + 0.01 * rng.standard_normal((m, 3)), "theta": theta,
                      "phi": np.full(m, phi), "ee_position": ee},
            "link_clearance": clearance,
            "metrics": {"goal_distance": float(np.linalg.norm(goal_position - ee)),
                        "predicted_min_distance": float(clearance.min() + 0.01 * np.sin(k)),
                        "true_min_distance": float(clearance.min()),
                        "solver_ms": float(10 + rng.random())},
        }


def main(argv: list[str] | None = None) -> int:
    from recorder.cli import OneLineParser, path_text, positive
    from recorder.recorder import MCAP_MESH_EVERY, Recorder

    parser = OneLineParser(prog="python -m recorder.synthetic", description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=path_text, help="output path without suffix")
    parser.add_argument("--steps", type=positive, default=20)
    parser.add_argument("--links", type=positive, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dt", type=float, default=0.05, help="sim time per step [s]")
    parser.add_argument("--pose-goal", action="store_true", help="a pose goal (approach along +x)")
    parser.add_argument("--viewer", nargs="?", const=True, default=False, metavar="URL",
                        help="also stream to a Rerun Viewer (the local one, or the one at URL)")
    parser.add_argument("--mcap-mesh-every", type=positive, default=MCAP_MESH_EVERY)
    parser.add_argument("--flush-every", type=positive, default=50)
    parser.add_argument("--step-delay", type=float, default=0.0, help="wall seconds to wait after each step")
    parser.add_argument("--print-steps", action="store_true", help="print 'step K' after each recorded step")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    if not (0 < args.dt < math.inf and 0 <= args.step_delay < math.inf):
        parser.error(f"--dt must be finite and > 0, and --step-delay finite and >= 0, "
                     f"got {args.dt} and {args.step_delay}")
    if isinstance(args.viewer, str):
        try:
            check_url(args.viewer)
        except ValueError as exc:
            parser.error(str(exc))

    run = SyntheticRun(links=args.links, seed=args.seed, pose_goal=args.pose_goal)
    try:
        with Recorder(args.out, run.meta, overwrite=args.overwrite, mcap_mesh_every=args.mcap_mesh_every,
                      flush_every=args.flush_every, safety_margin=run.safety_margin,
                      goal_tolerance=run.goal_tolerance, viewer=args.viewer) as rec:
            for k in range(args.steps):
                rec.log_step(k, k * args.dt, **run.step(k))
                if args.print_steps:
                    print(f"step {k}", flush=True)
                time.sleep(args.step_delay)
            rec.finish({"outcome": "success", "steps": args.steps, "reach_step": args.steps - 1,
                        "min_true_distance": 0.03, "first_collision_step": None})
    except RecorderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RecordingInterrupted as exc:
        from recorder.cli import EXIT_STATUS

        print(f"interrupted: {exc}", file=sys.stderr)
        return EXIT_STATUS[exc.signum]
    return 0


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
