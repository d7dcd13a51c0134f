"""The route's plans with lazy edge checks against checking every edge: ``python bench/route_plan.py``.

    python bench/route_plan.py
    python bench/route_plan.py --links 4,7 --starts 10

``ncedf.route.plan_route`` searches its roadmap lazily (``lazy_shortest_path``:
the shortest path over the edges not yet found blocked, only its edges checked,
repeated). The reference checks every edge before its search: the same function
with ``RouteConfig.lazy_rounds`` = 1, which checks all edges at once after the
first path.
Both plan from the same states, in the cluttered scene, to its goal, round the
convex model of its boxes observed at the scene's density (as the controller
fits it; the moving spheres are not in a plan's model). The starts are random
valid states close to a box, as a stalled robot is: clearance to the model in
[``edge_clearance``, ``node_clearance``). Printed per link count: the median
plan time of each (after one untimed plan that compiles), their ratio, and in
how many starts both found the same route (they must: the shortest path over
the clear edges), or both none.

The printed figures, measured, are in ``docs/experiments.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import numpy as np

from arguments import link_counts, positive
from ncedf import route
from ncedf.convex import fit_polytopes
from ncedf.robot import RobotSpec, sample_arc_lengths
from recorder.cli import OneLineParser, exit_with
from rows import print_rows
from scenarios import cluttered
from ncedf.presets import CONVEX_LINK
from scenarios.observe import make_observer
from scenarios.world import World

#: Random states drawn to find the starts near a box.
DRAWS = 4000


def starts_near_a_box(spec: RobotSpec, polytopes, count: int, seed: int) -> np.ndarray:
    """(count, M, 3) valid states whose clearance to the polytopes is in [edge, node clearance)."""
    config = route.RouteConfig()
    drawn = np.asarray(sample_arc_lengths(jax.random.PRNGKey(seed), spec, (DRAWS, spec.n_links)), np.float32)
    clear = route.clearances(drawn, spec, polytopes)
    near = drawn[(clear >= config.edge_clearance) & (clear < config.node_clearance)]
    if len(near) < count:
        raise ValueError(f"only {len(near)} of {DRAWS} random states lie near a box; ask for fewer --starts")
    return near[:count]


def timed_plan(spec, polytopes, start, key, config: route.RouteConfig) -> tuple[np.ndarray | None, float]:
    """plan_route's route and wall time, s."""
    begin = time.perf_counter()
    path = route.plan_route(spec, polytopes, start, np.asarray(cluttered.GOAL), key, config)
    return path, time.perf_counter() - begin


def compare(links: int, args) -> dict:
    """Lazy and eager plans from ``args.starts`` starts near a box, ``links`` links."""
    spec = RobotSpec(links)
    boxes = World(boxes=cluttered.make_boxes(), density=cluttered.DENSITY)
    polytopes = fit_polytopes(np.asarray(make_observer(boxes, args.seed).observe(0.0)), CONVEX_LINK)
    starts = starts_near_a_box(spec, polytopes, args.starts, args.seed)
    key = jax.random.PRNGKey(args.seed)
    lazy_config = route.RouteConfig()
    eager_config = dataclasses.replace(lazy_config, lazy_rounds=1)
    timed_plan(spec, polytopes, starts[0], key, lazy_config)  # compiles
    lazy, eager, same, found = [], [], 0, 0
    for i, start in enumerate(starts):
        k = jax.random.fold_in(key, i)
        a, ta = timed_plan(spec, polytopes, start, k, lazy_config)
        b, tb = timed_plan(spec, polytopes, start, k, eager_config)
        lazy.append(ta)
        eager.append(tb)
        found += a is not None
        same += (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
    return {"links": links, "lazy": float(np.median(lazy)), "eager": float(np.median(eager)),
            "lazy_max": max(lazy), "same": same, "found": found}


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--links", type=link_counts, default=[4, 5, 7],
                   help="link counts (comma-separated; default 4,5,7)")
    p.add_argument("--starts", type=positive, default=5, help="start states per link count (default 5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the observation, starts and plans (default 0)")
    args = p.parse_args(argv)
    device = jax.devices()[0]
    print(f"jax {jax.__version__} on {device.platform} ({device.device_kind}); cluttered scene, its goal")
    print(f"{'links':>5} {'starts':>6} {'routes':>6} {'lazy s':>7} {'(max)':>6} {'eager s':>8} {'eager/lazy':>10} "
          f"{'same':>5}")

    def lines(links):
        try:
            r = compare(links, args)
        except ValueError as err:
            p.error(str(err))
        return [f"{r['links']:>5} {args.starts:>6} {r['found']:>6} {r['lazy']:>7.2f} {r['lazy_max']:>6.2f} "
                f"{r['eager']:>8.2f} {r['eager'] / r['lazy']:>10.2f} {r['same']:>5}"]

    return print_rows(args.links, lines)


if __name__ == "__main__":
    exit_with(main())
