"""A short closed loop (MPPI on the exact geometry) recorded to both formats and read back."""

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from ncedf.geometry import robot_mesh_arrays, robot_signed_distance
from ncedf.controller import Controller, ControllerConfig
from ncedf.mppi import MPPIConfig
from ncedf.robot import RobotSpec, arc_lengths_to_config, forward_kinematics
from ncedf.shapes import make_shape
from recorder import Recorder, load_run

STEPS = 4


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    spec = RobotSpec(4)
    config = ControllerConfig(MPPIConfig(samples=32, horizon=5))
    mppi = Controller(spec, make_shape("exact", spec), config)
    state = mppi.init(jax.random.PRNGKey(0))
    arc = spec.straight_state()
    goal = jnp.array([2.0, 1.0, 6.0])
    obstacles = jnp.array([[1.5, 0.0, 4.0], [1.5, 0.3, 4.2], [-1.0, 1.0, 5.0]])
    out = tmp_path_factory.mktemp("runs") / "episode"
    sent = []
    with Recorder(out, {"scenario": "integration", "links": 4, "seed": 0}, safety_margin=config.mppi.safety_margin) as rec:
        for k in range(STEPS):
            action, state, info = mppi.step(state, arc, goal, obstacles)
            arc = arc + action * config.mppi.dt
            vertices, faces = robot_mesh_arrays(arc, spec, rings=8, around=8)
            frames = forward_kinematics(arc, spec)
            theta, phi = arc_lengths_to_config(arc, spec)
            ee = np.asarray(frames[-1, :3, 3])
            metrics = {
                "goal_distance": float(np.linalg.norm(ee - np.asarray(goal))),
                "predicted_min_distance": float(info.predicted_min_distance),
                "true_min_distance": float(jnp.min(robot_signed_distance(obstacles, arc, spec))),
                "solver_ms": 1.0 + k,
            }
            state_row = {"arc_lengths": np.asarray(arc), "theta": np.asarray(theta), "phi": np.asarray(phi),
                         "ee_position": ee}
            rec.log_step(k, k * config.mppi.dt, metrics=metrics, mesh_vertices=vertices, mesh_triangles=faces,
                         backbone=np.asarray(frames[:, :3, 3])[None], obstacle_points=np.asarray(obstacles),
                         goal=np.asarray(goal), plan=np.asarray(info.plan), state=state_row)
            sent.append((metrics, state_row))
        rec.finish({"outcome": "stuck", "steps": STEPS})
    return out, sent


@pytest.mark.parametrize("suffix", [".rrd", ".mcap"])
def test_every_step_reads_back_as_sent(recorded, suffix):
    out, sent = recorded
    run = load_run(out.with_suffix(suffix))
    assert run.complete and run.outcome["outcome"] == "stuck" and len(run.metrics) == STEPS
    for k, (metrics, state_row) in enumerate(sent):
        row = run.metrics.iloc[k]
        for name, value in metrics.items():
            assert row[name] == pytest.approx(value, rel=1e-6)
        st = run.state.iloc[k]
        np.testing.assert_allclose([st[f"arc_{i + 1}_{j + 1}"] for i in range(4) for j in range(3)],
                                   state_row["arc_lengths"].ravel(), rtol=1e-6)
        np.testing.assert_allclose([st["ee_x"], st["ee_y"], st["ee_z"]], state_row["ee_position"], rtol=1e-6)


def test_both_formats_give_equal_tables(recorded):
    out, _ = recorded
    rrd, mcap = load_run(out.with_suffix(".rrd")), load_run(out.with_suffix(".mcap"))
    pd.testing.assert_frame_equal(rrd.metrics, mcap.metrics)
    pd.testing.assert_frame_equal(rrd.state, mcap.state)
