"""What the viewers draw: the clearance colour map against its closed form, and the display fields
(link colours, goal region and approach arrow, plan knots, goal tolerance) read back from both formats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from recorder_readback import mcap_messages, rrd_columns, rrd_layouts, xyz

from recorder import Recorder, load_run, schema, style
from recorder.synthetic import SyntheticRun

LINKS, DT, MARGIN, TOL = 4, 0.05, 0.05, 0.4
STEPS = (0, 7, 36)  # synthetic steps with links in collision, near the margin and far
RED, ORANGE, YELLOW, GREEN, BLUE = (np.array(c) for c in (style.COLLISION_COLOR, style.MARGIN_COLOR,
                                                          style.NEAR_COLOR, style.CLEAR_COLOR, style.FAR_COLOR))


# ---------------------------------------------------------------- the colour map
def test_colour_map_at_its_anchors_and_between():
    """Red at and below 0, orange at the margin, yellow at 2 margins, green halfway to 1 m, blue from 1 m;
    linear in between (each channel rounded to the nearest byte); NaN is the plain robot colour."""
    m = MARGIN
    d = [-0.5, 0.0, m / 3, m, 1.6 * m, 2 * m, (2 * m + 1.0) / 2, 1.0, 7.0, np.inf, -np.inf, np.nan]
    expected = [RED, RED, RED + (ORANGE - RED) / 3, ORANGE, ORANGE + 0.6 * (YELLOW - ORANGE), YELLOW, GREEN, BLUE,
                BLUE, BLUE, RED, np.array(style.UNKNOWN_CLEARANCE_COLOR)]
    got = style.clearance_colors(np.array(d), m)
    assert got.dtype == np.uint8 and got.shape == (len(d), 3)
    np.testing.assert_array_equal(got, np.floor(np.array(expected) + 0.5))


def test_colour_map_far_end_grows_with_a_wide_margin():
    """With a margin of 0.5 m, 4 margins (2 m) exceed 1 m: blue starts at 2 m, green is at 1.5 m."""
    got = style.clearance_colors([0.5, 1.0, 1.5, 2.0], 0.5)
    np.testing.assert_array_equal(got, np.array([ORANGE, YELLOW, GREEN, BLUE]))


@pytest.mark.parametrize("margin", [0.0, -0.1, np.nan])
def test_colour_map_needs_a_positive_margin(margin):
    with pytest.raises(ValueError, match="safety margin > 0"):
        style.clearance_colors([0.1], margin)


def test_pack_rgba():
    assert style.pack_rgba(np.array([[1, 2, 3], [255, 0, 16]], dtype=np.uint8)).tolist() == [0x010203FF, 0xFF0010FF]


# ---------------------------------------------------------------- display fields in the files
def record(out: Path, pose_goal: bool) -> tuple[SyntheticRun, list[dict]]:
    run = SyntheticRun(links=LINKS, seed=3, rings=6, ring_points=5, n_points=20, horizon=4, pose_goal=pose_goal)
    sent = [run.step(k) for k in STEPS]
    with Recorder(out, run.meta, safety_margin=MARGIN, goal_tolerance=TOL) as rec:
        assert rec.goal_tolerance == TOL and rec.safety_margin == MARGIN
        for k, kwargs in zip(STEPS, sent):
            rec.log_step(k, k * DT, **kwargs)
        rec.finish({"outcome": "success", "steps": len(STEPS)})
    return run, sent


@pytest.fixture(scope="module", params=[False, True], ids=["position-goal", "pose-goal"])
def recorded(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("display") / "run"
    run, sent = record(out, pose_goal=request.param)
    return out, run, sent, request.param


def goal_parts(s: dict) -> tuple[np.ndarray, np.ndarray | None]:
    g = np.asarray(s["goal"])
    return (g[:3, 3], g[:3, :3]) if g.shape == (4, 4) else (g, None)


def test_sent_clearances_span_the_colour_map(recorded):
    """The recorded steps have links in collision, near the margin and far (beyond 1 m) from obstacles."""
    _, _, sent, _ = recorded
    d = np.concatenate([s["link_clearance"] for s in sent])
    assert d.min() < 0 and np.any((d > 0) & (d < 2 * MARGIN)) and d.max() > style.FAR_CLEARANCE


def test_rrd_holds_link_colours_goal_region_and_plan_knots(recorded):
    out, run, sent, pose = recorded
    cols = rrd_columns(out.with_suffix(".rrd"))
    per_link = run.rings * run.ring_points
    for k, s in enumerate(sent):
        link_rgba = style.pack_rgba(style.clearance_colors(s["link_clearance"], MARGIN))
        assert cols[(schema.MESH, "Mesh3D:vertex_colors")][k] == np.repeat(link_rgba, per_link).tolist()
        assert cols[(schema.BACKBONE, "LineStrips3D:colors")][k] == link_rgba.tolist()
        np.testing.assert_array_equal(cols[(schema.PLAN, "Points3D:positions")][k], s["plan"].astype(np.float32))
        position, rotation = goal_parts(s)
        np.testing.assert_allclose(cols[(f"{schema.GOAL_MARKER}/region", "Ellipsoids3D:centers")][k], [position],
                                   rtol=1e-6)
        if pose:
            axis = rotation[:, 2] * style.APPROACH_LENGTH * TOL
            np.testing.assert_allclose(cols[(f"{schema.GOAL_MARKER}/approach", "Arrows3D:vectors")][k], [axis],
                                       atol=1e-6)
            np.testing.assert_allclose(cols[(f"{schema.GOAL_MARKER}/approach", "Arrows3D:origins")][k],
                                       [position - axis], rtol=1e-6)
    has_arrow = any(entity == f"{schema.GOAL_MARKER}/approach" for entity, _ in cols)
    assert has_arrow == pose
    np.testing.assert_allclose(cols[(f"{schema.GOAL_MARKER}/region", "Ellipsoids3D:half_sizes")], [[[TOL] * 3]],
                               rtol=1e-6)  # static, once
    assert cols[(schema.GOAL_TOLERANCE, "Scalars:scalars")] == [[TOL]] * len(STEPS)
    assert (schema.MESH, "Mesh3D:albedo_factor") not in cols  # nothing tints the vertex colours


def test_mcap_holds_link_colours_goal_region_and_plan_knots(recorded):
    out, run, sent, pose = recorded
    msgs = mcap_messages(out.with_suffix(".mcap"))
    per_link = run.rings * run.ring_points
    assert [t for t, _ in msgs[schema.GOAL_MARKER]] == [round(k * DT * 1e9) for k in STEPS]
    for k, s in enumerate(sent):
        rgb = style.clearance_colors(s["link_clearance"], MARGIN) / 255
        mesh = msgs[schema.MESH][k][1].entities[0].triangles[0]
        np.testing.assert_array_equal([[c.r, c.g, c.b, c.a] for c in mesh.colors],
                                      np.repeat(np.c_[rgb, np.ones(LINKS)], per_link, axis=0))
        lines = msgs[schema.BACKBONE][k][1].entities[0].lines
        np.testing.assert_array_equal([[l.color.r, l.color.g, l.color.b] for l in lines], rgb)
        plan = msgs[schema.PLAN][k][1].entities[0]
        np.testing.assert_array_equal(xyz([p.pose.position for p in plan.spheres]), s["plan"].astype(np.float32))
        assert plan.lines[0].thickness == pytest.approx(2 * style.PLAN_RADIUS)
        marker = msgs[schema.GOAL_MARKER][k][1].entities[0]
        position, rotation = goal_parts(s)
        (region,) = marker.spheres
        np.testing.assert_array_equal(xyz([region.pose.position]), [position])
        np.testing.assert_allclose(xyz([region.size]), [[2 * TOL] * 3])
        assert region.color.a == pytest.approx(style.GOAL_REGION_ALPHA / 255)
        if not pose:
            assert not marker.arrows
            continue
        (arrow,) = marker.arrows
        q = arrow.pose.orientation
        x_axis = np.array([1 - 2 * (q.y ** 2 + q.z ** 2), 2 * (q.x * q.y + q.w * q.z), 2 * (q.x * q.z - q.w * q.y)])
        np.testing.assert_allclose(x_axis, rotation[:, 2], atol=1e-12)  # foxglove arrows point along +x
        length = arrow.shaft_length + arrow.head_length
        assert length == pytest.approx(style.APPROACH_LENGTH * TOL)
        np.testing.assert_allclose(xyz([arrow.pose.position]), [position - length * rotation[:, 2]], atol=1e-12)


def test_tables_still_equal_across_formats(recorded):
    out, _, sent, _ = recorded
    a, b = load_run(out.with_suffix(".rrd")), load_run(out.with_suffix(".mcap"))
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    pd.testing.assert_frame_equal(a.state, b.state)
    assert a.metrics["true_min_distance"].tolist() == [s["metrics"]["true_min_distance"] for s in sent]


# ---------------------------------------------------------------- arguments
def test_no_tolerance_no_marker_and_default_colour_margin(tmp_path):
    """Without goal_tolerance nothing is drawn around the goal; without a safety margin the colour map
    uses `style.COLOR_MAP_MARGIN`."""
    run = SyntheticRun(links=2, seed=0, rings=3, ring_points=4, n_points=5, horizon=3)
    step = run.step(0)
    with Recorder(tmp_path / "r", run.meta) as rec:
        assert rec.goal_tolerance is None
        rec.log_step(0, 0.0, **step)
    cols = rrd_columns(tmp_path / "r.rrd")
    assert not any(entity.startswith(schema.GOAL_MARKER) or entity == schema.GOAL_TOLERANCE for entity, _ in cols)
    assert schema.GOAL_MARKER not in mcap_messages(tmp_path / "r.mcap")
    expected = style.pack_rgba(style.clearance_colors(step["link_clearance"], style.COLOR_MAP_MARGIN))
    assert cols[(schema.BACKBONE, "LineStrips3D:colors")] == [expected.tolist()]


def test_bad_display_arguments(tmp_path):
    with pytest.raises(ValueError, match="goal_tolerance must be a finite distance"):
        Recorder(tmp_path / "a", {}, goal_tolerance=-0.1)
    run = SyntheticRun(links=2, seed=0, rings=3, ring_points=4, n_points=5, horizon=3)
    step = run.step(0)
    with Recorder(tmp_path / "b", {}, safety_margin=0.05) as rec:
        with pytest.raises(ValueError, match=r"link_clearance must have shape \(M,\)"):
            rec.log_step(0, 0.0, **{**step, "link_clearance": np.zeros((2, 1))})
        with pytest.raises(ValueError, match=r"mesh_vertices \(24\) must split into 5 links"):
            rec.log_step(0, 0.0, **{**step, "link_clearance": np.zeros(5), "backbone": None, "state": None})
        with pytest.raises(ValueError, match="backbone has 2 polylines, link_clearance 3 links"):
            rec.log_step(0, 0.0, metrics={}, backbone=step["backbone"], link_clearance=np.zeros(3))
        with pytest.raises(ValueError, match="link_clearance has 3 links, the state 2"):
            rec.log_step(0, 0.0, metrics={}, state=step["state"], link_clearance=np.zeros(3))
    with Recorder(tmp_path / "c", {}, safety_margin=0.0) as rec:
        with pytest.raises(ValueError, match="safety margin > 0"):
            rec.log_step(0, 0.0, metrics={}, link_clearance=np.zeros(2))


# ---------------------------------------------------------------- the stored layout
PLOTS = {"goal distance [m]", "clearance [m]", "solver [ms]"}


def test_the_layout_has_a_view_for_what_the_run_logs_and_no_empty_plot(tmp_path, recorded):
    """A closed-loop run's standard metrics: the world, their three plots and the log, no plot of other
    metrics; a run of metrics alone (training): no 3D view, no empty plot; a metric first logged at a later
    step adds its plot (each blueprint sent after the first is made active: the viewer shows the last)."""
    out = recorded[0]
    assert rrd_layouts(out.with_suffix(".rrd")) == [{"world", *PLOTS, "log"}]
    with Recorder(tmp_path / "train", {"kind": "training"}, formats=("rrd",)) as rec:
        for k in range(3):
            rec.log_step(k, float(k), metrics={"loss": 1.0 / (k + 1)})
        rec.finish({"outcome": "success", "steps": 3})
    assert rrd_layouts(tmp_path / "train.rrd")[-1] == {"other metrics", "log"}
    with Recorder(tmp_path / "later", {"kind": "episode"}, formats=("rrd",)) as rec:
        for k in range(3):
            rec.log_step(k, k * DT, metrics={"goal_distance": 1.0, **({"goal_angle": 0.2} if k == 2 else {})},
                         goal=np.zeros(3))
        rec.finish({"outcome": "success", "steps": 3})
    assert rrd_layouts(tmp_path / "later.rrd")[-2:] == [{"world", "goal distance [m]", "log"},
                                                        {"world", "goal distance [m]", "other metrics", "log"}]
