"""The controller's building blocks jitted, as ``ncedf.mppi.mppi_step`` runs them inside its
program. Called eagerly, JAX compiles each of their operations apart: tens of seconds a call
on the test machine, against a few for the whole program."""

import jax

from ncedf import broad_phase, convex, safety

#: (dt, substeps, broad, shape, arc, actions, points, mask, model=None, shared=False)
step_clearance = jax.jit(safety.step_clearance, static_argnums=(0, 1, 2), static_argnames="shared")
#: (broad, shape, arcs, points, mask, frames=None)
rollout_min_distances = jax.jit(broad_phase.rollout_min_distances, static_argnums=0)
#: (arcs, frames, spec, polytopes, t=0.0, dense=None, turning=False)
robot_clearance = jax.jit(convex.robot_clearance, static_argnums=2, static_argnames=("dense", "turning"))
#: (x, polytopes, t=0.0, dense=None, turning=False)
polytope_distance = jax.jit(convex.polytope_distance, static_argnames=("dense", "turning"))
