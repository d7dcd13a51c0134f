"""Solver time per MPPI step of several controllers on one scene, stepped in turn.

A helper of the timing benches (``closed_loop.py --timing``, ``paper_timing.py``),
imported from their folder.
"""

from __future__ import annotations

import time

import jax
import numpy as np

from scenarios.episode import Episode


def solver_times(named: dict[str, Episode], steps: int) -> dict[str, np.ndarray]:
    """Wall-clock ms of ``steps`` MPPI steps of each named prepared episode's controller, shape (steps,) each.

    Every controller starts from its scene's start: the straight robot, its plan
    at ``init``. Step k observes the cloud at time k dt (moving obstacles move,
    as in an episode) and keeps the robot where it is. The controllers take one
    step each in turn, so all of them see the same machine load; the first
    (compiling) step is not timed, and each timed step waits for its result
    (``jax.block_until_ready``).
    """
    controllers = {}
    for name, episode in named.items():
        scene = episode.scene
        arc = np.asarray(scene.spec.straight_state(), np.float32)
        state = episode.mppi.init(jax.random.PRNGKey(episode.settings.seed))
        jax.block_until_ready(episode.mppi.step(state, arc, scene.goal, scene.observer.observe(0.0)))  # compile
        controllers[name] = (episode.mppi, state, arc, scene)
    times = {name: [] for name in controllers}
    for k in range(1, steps + 1):
        for name, (mppi, state, arc, scene) in controllers.items():
            points = scene.observer.observe(k * scene.config.mppi.dt)
            mppi.prepare(state, arc, scene.goal, points)  # as an episode: a route's first plan compiled untimed
            start = time.perf_counter()
            _, state, _ = jax.block_until_ready(mppi.step(state, arc, scene.goal, points))
            times[name].append((time.perf_counter() - start) * 1e3)
            controllers[name] = (mppi, state, arc, scene)
    return {name: np.asarray(t) for name, t in times.items()}
