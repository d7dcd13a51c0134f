"""A short synthetic run recorded to both formats and read back: every value against what was sent."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import rerun.chunk as rc
from recorder_readback import mcap_messages, rrd_columns, xyz

from recorder import Recorder, load_run, load_runs, load_summaries, schema
from recorder.synthetic import SyntheticRun

RERUN = str(Path(sys.executable).with_name("rerun"))
STEPS, LINKS, DT = 3, 4, 0.05
OUTCOME = {"outcome": "collision", "steps": STEPS, "reach_step": None, "min_true_distance": -0.001,
           "first_collision_step": 2}


def record(out: Path, seed: int = 0) -> tuple[SyntheticRun, list[dict]]:
    run = SyntheticRun(links=LINKS, seed=seed, rings=5, ring_points=8, n_points=50, horizon=6)
    sent = [run.step(k) for k in range(STEPS)]
    with Recorder(out, {**run.meta, "run_id": "r0"}, safety_margin=0.02) as rec:
        for k, kwargs in enumerate(sent):
            rec.log_step(k, k * DT, **kwargs)
            rec.log_text(f"hello {k}", "warning")
        rec.finish(OUTCOME)
    return run, sent


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("rt") / "run"
    run, sent = record(out)
    return out, run, sent


def expected_metrics(sent) -> pd.DataFrame:
    rows = [{"step": k, "sim_time": k * DT, **s["metrics"]} for k, s in enumerate(sent)]
    return pd.DataFrame(rows).astype({"step": "int64"})


def expected_state(sent) -> pd.DataFrame:
    rows = [{"step": k, "sim_time": k * DT, **schema.flatten_state(s["state"])} for k, s in enumerate(sent)]
    return pd.DataFrame(rows).astype({"step": "int64"})


@pytest.mark.parametrize("fmt", ["rrd", "mcap"])
def test_tables_hold_what_was_sent(recorded, fmt):
    out, run, sent = recorded
    r = load_run(out.with_suffix(f".{fmt}"))
    assert r.complete and r.format == fmt
    assert r.meta == {**run.meta, "run_id": "r0"}
    assert r.outcome == OUTCOME
    pd.testing.assert_frame_equal(r.metrics, expected_metrics(sent))
    pd.testing.assert_frame_equal(r.state, expected_state(sent))
    assert list(r.state.columns[2:5]) == ["arc_1_1", "arc_1_2", "arc_1_3"]
    assert list(r.state.columns[-3:]) == ["ee_x", "ee_y", "ee_z"]


def test_both_formats_give_equal_tables(recorded):
    out, _, _ = recorded
    a, b = load_run(out.with_suffix(".rrd")), load_run(out.with_suffix(".mcap"))
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    pd.testing.assert_frame_equal(a.state, b.state)
    assert (a.meta, a.outcome) == (b.meta, b.outcome)


def test_rrd_display_entities_hold_what_was_sent(recorded):
    out, run, sent = recorded
    cols = rrd_columns(out.with_suffix(".rrd"))

    def per_step(entity, component):
        return [np.asarray(v, dtype=np.float64) for v in cols[(entity, component)]]

    assert np.array_equal(np.asarray(cols[(schema.MESH, "Mesh3D:triangle_indices")][0]), run.triangles)
    for k, s in enumerate(sent):
        np.testing.assert_array_equal(per_step(schema.MESH, "Mesh3D:vertex_positions")[k],
                                      s["mesh_vertices"].astype(np.float32))
        np.testing.assert_array_equal(per_step(schema.OBSTACLE_POINTS, "Points3D:positions")[k],
                                      s["obstacle_points"].astype(np.float32))
        strips = cols[(schema.BACKBONE, "LineStrips3D:strips")][k]
        np.testing.assert_array_equal(np.asarray(strips), s["backbone"].astype(np.float32))
        np.testing.assert_array_equal(np.asarray(cols[(schema.PLAN, "LineStrips3D:strips")][k][0]),
                                      s["plan"].astype(np.float32))
        np.testing.assert_array_equal(per_step(schema.GOAL, "Points3D:positions")[k][0],
                                      s["goal"].astype(np.float32))
        spheres = s["obstacle_shapes"]["spheres"]
        np.testing.assert_allclose(per_step(f"{schema.OBSTACLE_SHAPES}/spheres", "Ellipsoids3D:centers")[k],
                                   spheres["centers"], rtol=1e-6)
        np.testing.assert_allclose(per_step(f"{schema.OBSTACLE_SHAPES}/spheres", "Ellipsoids3D:half_sizes")[k],
                                   np.repeat(spheres["radii"][:, None], 3, axis=1), rtol=1e-6)
        boxes = s["obstacle_shapes"]["boxes"]
        np.testing.assert_allclose(per_step(f"{schema.OBSTACLE_SHAPES}/boxes", "Boxes3D:half_sizes")[k],
                                   boxes["sizes"] / 2, rtol=1e-6)
    assert cols[(schema.LOG, "TextLog:text")] == [[f"hello {k}"] for k in range(STEPS)]
    assert cols[(schema.LOG, "TextLog:level")] == [["WARN"]] * STEPS
    assert cols[(schema.SAFETY_MARGIN, "Scalars:scalars")] == [[0.02]] * STEPS
    assert cols[(schema.METRICS + "/goal_distance", "step")] == list(range(STEPS))
    assert not {name for _, name in cols} & {"log_time", "log_tick"}  # no wall clock
    reader = rc.RrdReader(out.with_suffix(".rrd"))
    assert [b.application_id for b in reader.blueprints()] == ["ncedf"]  # the stored default blueprint


def test_mcap_display_topics_hold_what_was_sent(recorded):
    out, run, sent = recorded
    msgs = mcap_messages(out.with_suffix(".mcap"))
    for topic in (schema.MESH, schema.BACKBONE, schema.OBSTACLE_POINTS, schema.OBSTACLE_SHAPES, schema.GOAL,
                  schema.PLAN, schema.STATE, schema.METRICS, schema.LOG):
        assert [t for t, _ in msgs[topic]] == [round(k * DT * 1e9) for k in range(STEPS)], topic
    for k, s in enumerate(sent):
        mesh = msgs[schema.MESH][k][1].entities[0].triangles[0]
        np.testing.assert_array_equal(xyz(mesh.points), s["mesh_vertices"].astype(np.float32))
        np.testing.assert_array_equal(np.array(mesh.indices), run.triangles.ravel())
        lines = msgs[schema.BACKBONE][k][1].entities[0].lines
        np.testing.assert_array_equal(np.stack([xyz(l.points) for l in lines]), s["backbone"].astype(np.float32))
        cloud = msgs[schema.OBSTACLE_POINTS][k][1]
        np.testing.assert_array_equal(np.frombuffer(cloud.data, "<f4").reshape(-1, 3),
                                      s["obstacle_points"].astype(np.float32))
        shapes = msgs[schema.OBSTACLE_SHAPES][k][1].entities[0]
        spheres = s["obstacle_shapes"]["spheres"]
        np.testing.assert_array_equal([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                                       for p in shapes.spheres], spheres["centers"])
        np.testing.assert_array_equal([p.size.x for p in shapes.spheres], 2 * spheres["radii"])
        np.testing.assert_array_equal([[c.size.x, c.size.y, c.size.z] for c in shapes.cubes],
                                      s["obstacle_shapes"]["boxes"]["sizes"])
        goal = msgs[schema.GOAL][k][1]
        np.testing.assert_array_equal([goal.translation.x, goal.translation.y, goal.translation.z], s["goal"])
        assert (goal.rotation.w, goal.parent_frame_id, goal.child_frame_id) == (1.0, "world", "goal")
        plan = msgs[schema.PLAN][k][1].entities[0].lines[0]
        np.testing.assert_array_equal(xyz(plan.points), s["plan"].astype(np.float32))
        assert msgs[schema.LOG][k][1].message == f"hello {k}"


@pytest.mark.parametrize("angle", [0.3, 3.0])  # trace of R > 0 and < 0: both branches of the conversion
def test_pose_goal_becomes_a_transform(tmp_path, angle):
    """A (4, 4) goal: Rerun Transform3D with its rotation, MCAP FrameTransform with the same quaternion."""
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    pose = np.eye(4)
    pose[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k  # Rodrigues
    pose[:3, 3] = [0.1, 0.2, 0.3]
    with Recorder(tmp_path / "g", {}) as rec:
        rec.log_step(0, 0.0, metrics={}, goal=pose)
        rec.finish({"outcome": "success"})
    goal = mcap_messages(tmp_path / "g.mcap")[schema.GOAL][0][1]
    q = np.array([goal.rotation.x, goal.rotation.y, goal.rotation.z, goal.rotation.w])
    expected = np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])
    np.testing.assert_allclose(q * np.sign(q @ expected), expected, atol=1e-12)
    cols = rrd_columns(tmp_path / "g.rrd")
    np.testing.assert_allclose(np.asarray(cols[(schema.GOAL, "Transform3D:mat3x3")][0]).reshape(3, 3).T,
                               pose[:3, :3], atol=1e-7)
    np.testing.assert_allclose(cols[(schema.GOAL, "Transform3D:translation")][0][0], pose[:3, 3], rtol=1e-6, atol=1e-7)


def test_the_worlds_meshes_are_drawn_once_as_sent(tmp_path):
    """Two meshes logged before the steps: static Mesh3D entities in the .rrd and one SceneUpdate each at
    time 0 in the MCAP, their vertices and triangles as sent; a malformed mesh is refused by name."""
    tetra = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2],
                                                                                        [1, 2, 3]]))
    square = (np.array([[2, 0, 0], [3, 0, 0], [3, 1, 0], [2, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    with Recorder(tmp_path / "m", {}) as rec:
        with pytest.raises(ValueError, match="faces .F, 3. indexing them"):
            rec.log_meshes([(square[0], np.array([[0, 1, 4]]))])
        rec.log_meshes([tetra, square])
        rec.log_step(0, 0.0, metrics={})
        rec.finish({"outcome": "success"})
    cols = rrd_columns(tmp_path / "m.rrd")
    msgs = mcap_messages(tmp_path / "m.mcap")[schema.OBSTACLE_MESHES]
    assert [t for t, _ in msgs] == [0, 0]
    for i, (vertices, faces) in enumerate([tetra, square]):
        entity = f"{schema.OBSTACLE_MESHES}/{i}"
        np.testing.assert_allclose(np.asarray(cols[(entity, "Mesh3D:vertex_positions")][0]), vertices)
        np.testing.assert_array_equal(np.asarray(cols[(entity, "Mesh3D:triangle_indices")][0]), faces)
        entity_msg = msgs[i][1].entities[0]
        assert entity_msg.id == f"mesh{i}"
        triangles = entity_msg.triangles[0]
        np.testing.assert_allclose(xyz(triangles.points), vertices)
        np.testing.assert_array_equal(np.asarray(triangles.indices).reshape(-1, 3), faces)


def test_files_validate_with_rerun_cli(recorded, tmp_path):
    out, _, _ = recorded
    assert subprocess.run([RERUN, "rrd", "verify", str(out.with_suffix(".rrd"))], capture_output=True).returncode == 0
    converted = tmp_path / "converted.rrd"
    res = subprocess.run([RERUN, "mcap", "convert", str(out.with_suffix(".mcap")), "-o", str(converted)],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert subprocess.run([RERUN, "rrd", "verify", str(converted)], capture_output=True).returncode == 0
    entities = {c.entity_path for c in rc.RrdReader(converted).stream().to_chunks()}
    assert {schema.MESH, schema.OBSTACLE_POINTS, schema.METRICS} <= entities


def test_same_run_gives_the_same_recording(recorded, tmp_path):
    out, _, _ = recorded
    again = tmp_path / "run"
    record(again)
    assert again.with_suffix(".mcap").read_bytes() == out.with_suffix(".mcap").read_bytes()
    same = subprocess.run([RERUN, "rrd", "compare", "--unordered", str(out.with_suffix(".rrd")),
                           str(again.with_suffix(".rrd"))], capture_output=True)
    assert same.returncode == 0, same.stderr
    other = tmp_path / "other" / "run"
    record(other, seed=1)
    differ = subprocess.run([RERUN, "rrd", "compare", "--unordered", str(out.with_suffix(".rrd")),
                             str(other.with_suffix(".rrd"))], capture_output=True)
    assert differ.returncode != 0
    assert other.with_suffix(".mcap").read_bytes() != out.with_suffix(".mcap").read_bytes()


def test_metrics_only_runs_with_extra_keys_jax_inputs_and_nan(tmp_path):
    import jax.numpy as jnp

    sent = [{"loss": 1.0 / (k + 1), "lr": float("nan") if k == 1 else 1e-3, "val_mae": None} for k in range(4)]
    with Recorder(tmp_path / "train", {"kind": "training", "run_id": "t0"}) as rec:
        for k, m in enumerate(sent):
            rec.log_step(k, float(k), metrics={**m, "grad_norm": jnp.float32(0.5)})
        rec.log_step(4, 4.0, metrics={"loss": 0.1}, state={"arc_lengths": jnp.ones((2, 3)), "theta": jnp.zeros(2),
                                                             "phi": jnp.zeros(2), "ee_position": jnp.arange(3.0)})
        rec.finish({"outcome": "success", "steps": 5})
    a, b = load_run(tmp_path / "train.rrd"), load_run(tmp_path / "train.mcap")
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    pd.testing.assert_frame_equal(a.state, b.state)
    assert list(a.metrics.columns) == ["step", "sim_time", "grad_norm", "loss", "lr", "val_mae"]
    assert a.metrics["loss"].tolist() == [1.0, 0.5, 1 / 3, 0.25, 0.1]
    assert np.isnan(a.metrics["lr"][1]) and a.metrics["lr"][0] == 1e-3
    assert a.metrics["val_mae"].isna().all() and a.metrics["grad_norm"][:4].tolist() == [0.5] * 4
    assert a.state[["ee_x", "ee_y", "ee_z"]].values.tolist() == [[0.0, 1.0, 2.0]]
    assert a.outcome == b.outcome == {"outcome": "success", "steps": 5, "reach_step": None,
                                      "min_true_distance": None, "first_collision_step": None}


def test_load_runs_tables(recorded, tmp_path):
    out, run, sent = recorded
    for seed in (1, 2):
        with Recorder(tmp_path / "sub" / f"s{seed}", {"seed": seed, "mppi": {"horizon": 5}}, formats=("rrd",)) as rec:
            rec.log_step(0, 0.0, metrics={"goal_distance": seed})
    (tmp_path / "r0.mcap").write_bytes(out.with_suffix(".mcap").read_bytes())
    (tmp_path / "r0.rrd").write_bytes(out.with_suffix(".rrd").read_bytes())
    runs, steps = load_runs(tmp_path)
    assert runs["run_id"].tolist() == ["r0", "s1", "s2"]
    assert runs["format"].tolist() == ["mcap", "rrd", "rrd"]
    assert runs["outcome"].tolist() == ["collision", "interrupted", "interrupted"]
    assert runs["mppi.horizon"].tolist() == [run.meta["mppi"]["horizon"], 5, 5]
    assert runs["complete"].all()
    assert list(steps.columns[:3]) == ["run_id", "step", "sim_time"]
    r0 = steps[steps.run_id == "r0"].drop(columns="run_id").dropna(axis=1, how="all").reset_index(drop=True)
    pd.testing.assert_frame_equal(r0, expected_metrics(sent))
    assert steps.loc[steps.run_id == "s2", "goal_distance"].tolist() == [2.0]


def test_an_experiment_manifest_is_listed_apart_from_the_episodes(tmp_path):
    for name, scenario in (("episode", "cluttered"), ("experiment", schema.MANIFEST)):
        with Recorder(tmp_path / name, {"scenario": scenario}, formats=("mcap",)) as rec:
            rec.log_step(0, 0.0, metrics={"goal_distance": 1.0})
            rec.finish({"outcome": "success", "steps": 1})
    for read in (lambda **kw: load_runs(tmp_path, **kw)[0], lambda **kw: load_summaries(tmp_path, **kw)):
        assert read()["run_id"].tolist() == ["episode"]
        assert read(kind="manifests")["run_id"].tolist() == ["experiment"]
        assert read(kind="all")["run_id"].tolist() == ["episode", "experiment"]
        with pytest.raises(ValueError, match="'episode'"):
            read(kind="episode")


def test_ragged_backbones_and_empty_obstacles(tmp_path):
    lines = [np.zeros((3, 3)), np.arange(15.0).reshape(5, 3)]
    with Recorder(tmp_path / "e", {}) as rec:
        rec.log_text("before any step")
        rec.log_step(0, 0.0, metrics={"goal_distance": 1.0}, backbone=lines, obstacle_points=np.zeros((0, 3)),
                     obstacle_shapes={"spheres": {"centers": np.zeros((0, 3)), "radii": np.zeros(0)}})
        rec.log_step(1, 0.1, metrics={"goal_distance": 0.5}, backbone=lines[:1],
                     obstacle_shapes={"boxes": {"centers": np.zeros((2, 3)), "sizes": np.ones((2, 3))}})
        rec.finish({"outcome": "success"})
    a, b = load_run(tmp_path / "e.rrd"), load_run(tmp_path / "e.mcap")
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    assert subprocess.run([RERUN, "rrd", "verify", str(tmp_path / "e.rrd")], capture_output=True).returncode == 0
    strips = rrd_columns(tmp_path / "e.rrd")[(schema.BACKBONE, "LineStrips3D:strips")]
    assert [[len(s) for s in row] for row in strips] == [[3, 5], [3]]
    np.testing.assert_array_equal(strips[0][1], lines[1])
    mcap_lines = [m.entities[0].lines for _, m in mcap_messages(tmp_path / "e.mcap")[schema.BACKBONE]]
    assert [[len(l.points) for l in row] for row in mcap_lines] == [[3, 5], [3]]
