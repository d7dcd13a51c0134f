"""Broad phase against brute force near obstacles, per cloud density: ``python bench/broad_phase.py``.

    python bench/broad_phase.py
    python bench/broad_phase.py --densities 4,16,36 --links 4,5,7 --states 6 --shapes exact,ncedf

States: per link count, random configurations (``ncedf.robot.sample_arc_lengths``)
whose exact clearance to the cluttered world (``scenarios.cluttered``, t = 0) is
between 0.02 and 0.5 m: near a surface, where the collision cost decides. Around
each, the rollouts of the ``ours`` preset (its sampling, covariance, noise clip,
rollouts and horizon; zero nominal). Per density, the world is observed at that
many points per m^2 of box face (``scenarios.observe.make_observer``), and the
broad phase (``ncedf.broad_phase``; the preset's sizes) and brute force give
every rollout state's minimum distance to the cloud, per shape representation.

Printed per (density, links, shape): the rollout states compared; the share
within 1e-5 m of brute force; the share the broad phase over-estimates by more
than 2 cm (those rollouts look safer than they are), and the largest
over-estimate; the time of one call of each (N x H states, mean of ``--repeats``
after compilation) and their ratio.

The printed figures, measured, are in ``docs/experiments.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from arguments import parse_list, positive
from ncedf.broad_phase import rollout_min_distances_broad, rollout_min_distances_brute
from ncedf.sampling import bounded_controls, sample_noise
from ncedf.model import load_model
from ncedf.robot import RobotSpec, sample_arc_lengths
from ncedf.shapes import make_shape
from recorder.cli import OneLineParser, exit_with
from rows import print_rows
from scenarios import cluttered
from ncedf.presets import Observation, ours
from scenarios.observe import make_observer
from scenarios.truth import true_distances_batch

#: Clearance band of the sampled states, m.
NEAR = (0.02, 0.5)
#: An over-estimate by more than this counts, m.
OVER = 0.02
#: Configurations drawn per try when looking for states in the band.
DRAW = 4096


def near_states(spec: RobotSpec, count: int, seed: int) -> np.ndarray:
    """``count`` (M, 3) states with exact clearance to the boxes in ``NEAR`` (rejection sampling)."""
    world = dataclasses.replace(cluttered.make_world(), spheres=())
    key, found = jax.random.PRNGKey(seed), []
    for _ in range(50):
        key, sub = jax.random.split(key)
        arcs = np.asarray(sample_arc_lengths(sub, spec, (DRAW, spec.n_links)))
        d = true_distances_batch(world, spec, arcs, np.zeros(DRAW)).min(axis=1)
        found.extend(arcs[(d > NEAR[0]) & (d < NEAR[1])])
        if len(found) >= count:
            return np.stack(found[:count])
    raise RuntimeError(f"only {len(found)} states near the boxes after 50 draws")


def rollouts(spec: RobotSpec, controller, state: np.ndarray, key) -> jnp.ndarray:
    """(N, H, M, 3) rollout states of the ControllerConfig ``controller`` from ``state`` with a zero plan."""
    c, sampling = controller.mppi, controller.sampling
    nominal = jnp.zeros((c.horizon, spec.n_links, 3), jnp.float32)
    noise = sample_noise(sampling, c.covariance, c.samples, key, nominal.shape, jnp.float32)
    u = bounded_controls(sampling, c.control_bound, nominal[None] + noise)
    return jnp.asarray(state, jnp.float32) + c.dt * jnp.cumsum(u, axis=1)


def timed(fn, arg, repeats: int) -> tuple[np.ndarray, float]:
    out = jax.block_until_ready(fn(arg))
    start = time.perf_counter()
    for _ in range(repeats):
        jax.block_until_ready(fn(arg))
    return np.asarray(out), (time.perf_counter() - start) / repeats


def compare(density: float, links: int, shape_name: str, args, model) -> dict:
    """The broad phase against brute force on the same rollouts: one row."""
    spec = RobotSpec(links)
    cloud = make_observer(cluttered.make_world(density), args.seed).observe(0.0)
    controller = ours(spec, Observation(len(cloud)))
    config, broad_phase = controller.mppi, controller.broad_phase
    points = jnp.zeros((config.max_points, 3), jnp.float32).at[: len(cloud)].set(jnp.asarray(cloud, jnp.float32))
    mask = jnp.arange(config.max_points) < len(cloud)
    shape = make_shape(shape_name, spec, model=model if shape_name == "ncedf" else None)
    brute = jax.jit(lambda a: rollout_min_distances_brute(shape, a, points, mask))
    broad = jax.jit(lambda a: rollout_min_distances_broad(shape, a, points, mask, broad_phase.k1, broad_phase.k2,
                                                          broad_phase.capsule_segments))
    diffs, times = [], {"broad": [], "brute": []}
    for i, state in enumerate(near_states(spec, args.states, args.seed)):
        arcs = rollouts(spec, controller, state, jax.random.PRNGKey(args.seed + i))
        bf, t = timed(brute, arcs, 1)
        times["brute"].append(t)
        bp, t = timed(broad, arcs, args.repeats)
        diffs.append((bp - bf).ravel())
        times["broad"].append(t)
    d = np.concatenate(diffs)
    return {"density": density, "links": links, "shape": shape_name, "points": len(cloud), "states": d.size,
            "agree": float(np.mean(np.abs(d) <= 1e-5)), "over": float(np.mean(d > OVER)), "max_over": float(d.max()),
            "broad_ms": 1e3 * float(np.mean(times["broad"])), "brute_ms": 1e3 * float(np.mean(times["brute"]))}


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--densities", default="4,16", type=lambda t: parse_list(t, float, "densities", above_zero=True),
                   help="observed points per m^2 of box face (default 4,16)")
    p.add_argument("--links", default="4,5,7", type=lambda t: parse_list(t, int, "links", above_zero=True),
                   help="link counts (default 4,5,7)")
    p.add_argument("--shapes", default="exact,ncedf", help="representations (default exact,ncedf)")
    p.add_argument("--states", type=positive, default=4, help="states near the boxes per link count (default 4)")
    p.add_argument("--repeats", type=positive, default=3, help="timed broad-phase calls per state (default 3)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    shapes = [s.strip() for s in args.shapes.split(",") if s.strip()]
    model = load_model() if "ncedf" in shapes else None
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}; ours preset rollouts from {args.states} states "
          f"per link count with exact clearance {NEAR[0]}-{NEAR[1]} m to the boxes")
    print(f"{'density':>7} {'links':>5} {'shape':>8} {'points':>6} {'states':>7} {'agree':>7} "
          f"{'over 2cm':>8} {'max over':>8} {'broad ms':>9} {'brute ms':>9} {'ratio':>6}")
    groups = [(d, links, name) for d in args.densities for links in args.links for name in shapes]
    return print_rows(groups, lambda group: [
        f"{r['density']:>7g} {r['links']:>5} {r['shape']:>8} {r['points']:>6} {r['states']:>7} "
        f"{r['agree']:>7.4f} {r['over']:>8.4f} {r['max_over']:>8.3f} {r['broad_ms']:>9.1f} {r['brute_ms']:>9.1f} "
        f"{r['brute_ms'] / r['broad_ms']:>6.1f}" for r in [compare(*group, args, model)]])


if __name__ == "__main__":
    exit_with(main())
