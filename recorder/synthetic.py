"""Synthetic, deterministic robot-like runs for tests, benchmarks and trying the viewers.

A chain of M bending tubes (the "robot"), a cloud of obstacle points, two spheres and a box,
a goal and a planned path; every value is a function of (seed, step) alone.

    python -m recorder.synthetic OUT [--steps 20] [--links 4] [--step-delay 0] [--print-steps]

writes OUT.rrd and OUT.mcap (flush/mesh/overwrite options as in `Recorder`); with
`--print-steps` it prints `step K` after each recorded step (used by the interruption tests).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from recorder.errors import RecorderError, RecordingInterrupted

LINK_LENGTH = 0.1  # m
TUBE_RADIUS = 0.015  # m


def tube_triangles(links: int, rings: int, ring_points: int) -> np.ndarray:
    """Triangle indices (F, 3) of `links` tubes of `rings` x `ring_points` vertices (side walls only)."""
    tris = []
    for link in range(links):
        base = link * rings * ring_points
        for r in range(rings - 1):
            for p in range(ring_points):
                a = base + r * ring_points + p
                b = base + r * ring_points + (p + 1) % ring_points
                c, d = a + ring_points, b + ring_points
                tris += [(a, b, d), (a, d, c)]
    return np.asarray(tris, dtype=np.uint32)


def tube_vertices(backbone: np.ndarray, ring_points: int, radius: float = TUBE_RADIUS) -> np.ndarray:
    """Vertices (M * K * ring_points, 3) of tubes around polylines (M, K, 3); rings lie in x-y planes."""
    angles = np.linspace(0.0, 2 * np.pi, ring_points, endpoint=False)
    ring = radius * np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=-1)
    return (backbone[:, :, None, :] + ring[None, None, :, :]).reshape(-1, 3)


class SyntheticRun:
    """Deterministic step data for a robot of `links` links (mesh of links x rings x ring_points vertices)."""

    def __init__(self, links: int = 4, seed: int = 0, rings: int = 30, ring_points: int = 32,
                 n_points: int = 500, horizon: int = 20):
        self.links, self.seed, self.rings, self.ring_points = links, seed, rings, ring_points
        self.n_points, self.horizon = n_points, horizon
        self.triangles = tube_triangles(links, rings, ring_points)
        self.meta = {"scenario": "synthetic", "links": links, "seed": seed, "shape": "exact",
                     "mppi": {"horizon": horizon, "samples": 64}, "dt": 0.05}

    def step(self, k: int) -> dict:
        """Keyword arguments of `Recorder.log_step` for step k (everything but step and sim_time)."""
        rng = np.random.default_rng([self.seed, k])
        m = self.links
        theta = 0.3 * np.sin(0.1 * k + np.arange(m))
        phi = 0.5 * np.cos(0.05 * k + np.arange(m))
        s = np.linspace(0.0, 1.0, self.rings)
        z = (np.arange(m)[:, None] + s[None, :]) * LINK_LENGTH
        x = theta[:, None] * z * 0.2
        y = phi[:, None] * z * 0.1
        backbone = np.stack([x, y, z], axis=-1)
        ee = backbone[-1, -1]
        goal = np.array([0.1, 0.05, m * LINK_LENGTH * 0.8])
        return {
            "mesh_vertices": tube_vertices(backbone, self.ring_points),
            "mesh_triangles": self.triangles,
            "backbone": backbone,
            "obstacle_points": rng.normal([0.15, 0.0, 0.2], 0.03, size=(self.n_points, 3)),
            "obstacle_shapes": {"spheres": {"centers": np.array([[0.15, 0.0, 0.2], [-0.1, 0.1, 0.3]]),
                                            "radii": np.array([0.03, 0.05])},
                                "boxes": {"centers": np.array([[0.0, -0.2, 0.1]]),
                                          "sizes": np.array([[0.1, 0.1, 0.2]])}},
            "goal": goal,
            "plan": np.linspace(ee, goal, self.horizon),
            "state": {"arc_lengths": LINK_LENGTH + 0.01 * rng.standard_normal((m, 3)), "theta": theta, "phi": phi,
                      "ee_position": ee},
            "metrics": {"goal_distance": float(np.linalg.norm(goal - ee)),
                        "predicted_min_distance": float(0.05 + 0.01 * np.sin(k)),
                        "true_min_distance": float(0.04 + 0.01 * np.cos(k)),
                        "solver_ms": float(10 + rng.random())},
        }


def main(argv: list[str] | None = None) -> int:
    from recorder.recorder import MCAP_MESH_EVERY, Recorder

    parser = argparse.ArgumentParser(prog="python -m recorder.synthetic", description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="output path without suffix")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--links", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dt", type=float, default=0.05, help="sim time per step [s]")
    parser.add_argument("--mcap-mesh-every", type=int, default=MCAP_MESH_EVERY)
    parser.add_argument("--flush-every", type=int, default=50)
    parser.add_argument("--step-delay", type=float, default=0.0, help="wall seconds to wait after each step")
    parser.add_argument("--print-steps", action="store_true", help="print 'step K' after each recorded step")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)

    run = SyntheticRun(links=args.links, seed=args.seed)
    try:
        with Recorder(args.out, run.meta, overwrite=args.overwrite, mcap_mesh_every=args.mcap_mesh_every,
                      flush_every=args.flush_every, safety_margin=0.02) as rec:
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
        print(f"interrupted: {exc}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
