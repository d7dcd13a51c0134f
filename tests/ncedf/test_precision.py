"""Every matrix product of the controller, the network and the exact judge asks for full float32
precision (``ncedf.precision``): at the default, GPUs round their inputs to TF32."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.convex import fit_polytopes
from ncedf.model import load_model
from ncedf.controller import ControllerConfig
from ncedf.mppi import MPPIConfig, init_state, mppi_step
from ncedf.obstacle_model import ConvexModel
from ncedf.safety import SafetyFilter
from ncedf.sampling import Sampling
from ncedf.temperature import EffectiveSampleSize
from ncedf.precision import MATMUL
from ncedf.robot import RobotSpec
from ncedf.shapes import make_shape

SPEC = RobotSpec(2)
FULL = (MATMUL, MATMUL)


def dot_precisions(jaxpr) -> list:
    """The ``precision`` of every dot_general in ``jaxpr`` and the jaxprs nested in its equations."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            found.append(eqn.params["precision"])
        for value in eqn.params.values():
            for sub in value if isinstance(value, (tuple, list)) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    found += dot_precisions(inner)
    return found


def test_the_walker_sees_a_default_precision_product():
    x = jnp.ones((3, 3))
    closed = jax.make_jaxpr(lambda a: jax.lax.cond(True, lambda b: b @ b, lambda b: b, a))(x)
    assert dot_precisions(closed.jaxpr) == [None]


@pytest.mark.parametrize("stages", [
    {"sampling": Sampling(smoothing=0.5, unclipped=True), "model": ConvexModel(0.6),
     "safety": SafetyFilter(sweep_first=True), "temperature": EffectiveSampleSize(0.05)},
    {},
])
def test_controller_products_are_full_precision(stages):
    config = ControllerConfig(MPPIConfig(samples=8, horizon=3, max_points=16), **stages)
    shape = make_shape("ncedf", SPEC, model=load_model())
    rng = np.random.default_rng(0)
    points = rng.uniform(-2.0, 2.0, (16, 3)).astype(np.float32) + np.float32([3.0, 0.0, 2.0])
    mask = jnp.ones(16, bool)
    polytopes = fit_polytopes(points, config.model.link) if config.model else None
    state = init_state(SPEC, config.mppi, jax.random.PRNGKey(0))
    step = functools.partial(mppi_step, SPEC, config, shape)
    closed = jax.make_jaxpr(step)(state, jnp.asarray(SPEC.straight_state()), jnp.asarray([2.0, 0.0, 2.0]),
                                  jnp.asarray(points), mask, polytopes)
    precisions = dot_precisions(closed.jaxpr)
    assert precisions  # the network's layers at least
    assert all(p == FULL for p in precisions), precisions
