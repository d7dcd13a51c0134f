"""Which charging-port poses a robot can reach at all: ``python bench/charging_reach.py --links 4``.

The port of ``scenarios.charging`` is drawn anywhere in y in [-3, 3], z in [1, 5] on the plane x = 5,
and its goal is a pose: the tip at the port's centre, its approach axis along +x. Ignoring every
obstacle, this refines ``--starts`` random states towards each environment's pose by the route's
damped least squares (``ncedf.route``: the tip's position, its approach axis and the last link
straight behind it; ``--iterations`` steps) and counts the states that end within the scenario's
position and angle tolerances. An environment where none does is out of the robot's reach: a
numerical verdict (a local search from many starts), for the success rate a world can allow.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import jax  # noqa: E402
import numpy as np  # noqa: E402

from arguments import positive  # noqa: E402
from ncedf.robot import sample_arc_lengths  # noqa: E402
from ncedf.route import RouteConfig, _refined, ends  # noqa: E402
from recorder.cli import OneLineParser, exit_with, stoppable  # noqa: E402
from scenarios.charging import TOLERANCE  # noqa: E402
from scenarios.episode import ANGLE_TOLERANCE, EpisodeSettings, build_scene  # noqa: E402


def main(argv=None) -> int:
    p = OneLineParser(prog="python bench/charging_reach.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--links", type=positive, default=4, help="robot links (default 4)")
    p.add_argument("--envs", type=positive, default=10, help="environments 0..N-1 (default 10)")
    p.add_argument("--starts", type=positive, default=500, help="random starts per environment (default 500)")
    p.add_argument("--iterations", type=positive, default=300, help="least-squares steps (default 300)")
    args = p.parse_args(argv)
    config = RouteConfig(goal_candidates=args.starts, goal_iterations=args.iterations)
    out = 0
    for env in range(args.envs):
        scene = build_scene(EpisodeSettings(scenario="charging", links=args.links, env_seed=env, seed=0))
        spec, goal = scene.spec, np.asarray(scene.goal)
        starts = np.asarray(sample_arc_lengths(jax.random.PRNGKey(env), spec, (args.starts, spec.n_links)), np.float32)
        axes, tips = ends(_refined(starts, goal[:3, 3], spec, config, goal[:3, 2]), spec)
        error = np.linalg.norm(tips - goal[:3, 3], axis=1)
        angle = np.arccos(np.clip(axes @ goal[:3, 2], -1.0, 1.0))
        reached = int(np.sum((error <= TOLERANCE) & (angle <= ANGLE_TOLERANCE)))
        out += reached > 0
        print(f"env {env}: port at y {goal[1, 3]:+.2f}, z {goal[2, 3]:.2f} m ({np.linalg.norm(goal[:3, 3]):.2f} m from "
              f"the base): {reached} of {args.starts} states reach the pose; closest tip {error.min():.2f} m")
    print(f"{args.links} links: {out} of {args.envs} environments' poses within reach")
    return 0


if __name__ == "__main__":
    exit_with(stoppable(main))
