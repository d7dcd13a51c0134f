"""The convex model's clearance in passes (the CPU's form) against all at once (other devices'):
``python bench/convex_clearance.py``.

    python bench/convex_clearance.py
    python bench/convex_clearance.py --links 4,7 --repeats 20

``ncedf.convex.robot_clearance`` scores the rollout states of ``ours`` in the
cluttered scene. On the CPU it runs ``CLEARANCE_CHUNK`` states per pass and a
loop over the clusters that skips what a cluster lacks; on other devices it
scores every state against every cluster at once, with no loop or branch
(``jax.lax.platform_dependent``). This bench times both forms on the device JAX
runs on, at the preset's rollouts and horizon: random configurations (N, H, M,
3), each scored at its horizon step's time, against the polytopes of the
cluttered world observed at its density at its second step, fitted as the
controller fits them (its boxes, and its moving spheres as balls). Printed per
link count: both forms' time per call (median of ``--repeats`` after
compilation), their ratio, and their largest difference.

The printed figures, measured, are in ``docs/experiments.md``.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from arguments import link_counts, positive
from ncedf.controller import Controller
from ncedf.convex import robot_clearance
from ncedf.presets import Observation, ours
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths
from ncedf.shapes import make_shape
from recorder.cli import OneLineParser, exit_with
from rows import print_rows
from scenarios import cluttered
from scenarios.observe import make_observer

#: The forms timed: (name, ``dense`` argument of ``robot_clearance``).
FORMS = (("passes", False), ("at once", True))


def median_ms(fn, args, repeats: int) -> tuple[np.ndarray, float]:
    """fn(*args) after one compiling call, and the median wall time of ``repeats`` calls, ms."""
    out = jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return np.asarray(out), 1e3 * float(np.median(times))


def compare(links: int, args) -> dict:
    """Both forms on the preset's (N, H) rollout states of a ``links``-link robot."""
    spec = RobotSpec(links)
    observer = make_observer(cluttered.make_world(), args.seed)
    controller = Controller(spec, make_shape("spheres", spec), ours(spec, Observation(len(observer.observe(0.0)))))
    config = controller.config.mppi
    before = controller.pad_points(observer.observe(0.0))
    now = controller.pad_points(observer.observe(config.dt))  # its second step
    polytopes = controller.config.model.fit(*now, *before, config.dt)
    arcs = sample_arc_lengths(jax.random.PRNGKey(args.seed), spec, (config.samples, config.horizon, links))
    frames = forward_kinematics(arcs, spec)
    ahead = config.dt * jnp.arange(1, config.horizon + 1, dtype=arcs.dtype)
    row = {"links": links, "states": config.samples * config.horizon, "clusters": int(np.sum(polytopes.present))}
    outs = []
    for name, dense in FORMS:
        fn = jax.jit(lambda a, f, p, d=dense: robot_clearance(a, f, spec, p, ahead, dense=d))
        out, row[name] = median_ms(fn, (arcs, frames, polytopes), args.repeats)
        outs.append(out)
    row["max_diff"] = float(np.max(np.abs(outs[0] - outs[1])))
    return row


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--links", type=link_counts, default=[4, 5, 7],
                   help="link counts (comma-separated; default 4,5,7)")
    p.add_argument("--repeats", type=positive, default=10, help="timed calls per form (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of the observation and the states (default 0)")
    args = p.parse_args(argv)
    device = jax.devices()[0]
    print(f"jax {jax.__version__} on {device.platform} ({device.device_kind}); cluttered world, ours preset sizes")
    print(f"{'links':>5} {'states':>7} {'clusters':>8} {'passes ms':>10} {'at once ms':>11} {'ratio':>6} "
          f"{'max diff m':>11}")

    def lines(links):
        r = compare(links, args)
        return [f"{r['links']:>5} {r['states']:>7} {r['clusters']:>8} {r['passes']:>10.2f} {r['at once']:>11.2f} "
                f"{r['at once'] / r['passes']:>6.2f} {r['max_diff']:>11.1e}"]

    return print_rows(args.links, lines)


if __name__ == "__main__":
    exit_with(main())
