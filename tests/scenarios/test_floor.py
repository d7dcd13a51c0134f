"""scenarios.floor against closed forms and recordings read back.

Truths: the distance from a sphere to a disk in closed form; the first time a sphere moving at a
known speed reaches the base disk; a verdict's recording read back with ``recorder.load_run``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ncedf.robot import RobotSpec
from recorder import load_run
from scenarios import floor
from scenarios.oracle import OracleResult
from scenarios.world import MovingSphere, World

SPEC = RobotSpec(4)


def test_disk_gap_is_the_closed_form_distance_to_the_disk():
    r = SPEC.radius
    centres = np.array([[0.0, 0.0, 1.0], [3.0, 0.0, 0.0], [0.0, 2.0, -1.5], [r / 2, 0.0, 0.3], [3.0, 4.0, 1.0]])
    radii = np.array([0.5, 0.7, 0.2, 0.1, 1.0])
    expected = [1.0 - 0.5, 3.0 - r - 0.7, math.hypot(2.0 - r, 1.5) - 0.2, 0.3 - 0.1, math.hypot(5.0 - r, 1.0) - 1.0]
    np.testing.assert_allclose(floor.disk_gap(centres, radii, r), expected, atol=1e-12)


def test_a_sphere_falling_onto_the_base_hits_it_when_its_gap_closes():
    # 0.6 m above the disk, radius 0.5, falling at 1 m/s: it touches at t = 0.1 s, in step 2
    world = World(spheres=(MovingSphere((0.0, 0.0, 0.6), 0.5, (0.0, 0.0, -1.0), 10.0),))
    t = floor.first_base_hit(world, SPEC, 1.0, dt=0.001)
    assert 0.1 <= t <= 0.1 + 0.001 + 1e-9
    assert floor.hit_step(t) == 3 if t > 0.1 + 1e-9 else floor.hit_step(t) == 2
    assert floor.first_base_hit(World(spheres=(MovingSphere((0.0, 0.0, 3.0), 0.5, (0.0, 0.0, 0.0)),)), SPEC,
                                1.0) is None


@pytest.mark.parametrize("found", [True, False])
def test_a_verdict_reads_back_with_its_motion_and_facts(tmp_path, found):
    world = World(spheres=(MovingSphere((3.0, 0.0, 2.0), 0.7, (0.0, 1.0, 0.0), 2.0),))
    goal = np.array([4.0, 0.0, 4.0])
    arcs = np.repeat(np.asarray(SPEC.straight_state(), np.float64)[None], 4, axis=0)
    arcs[1:, 0, 0] += np.array([0.01, 0.02, 0.03])
    arcs[1:, 0, 1] -= np.array([0.01, 0.02, 0.03])
    result = OracleResult(3, 8, arcs, 0.42) if found else OracleResult(None, None, None, float("nan"))
    verdict = floor.Verdict(17 if not found else None, False, result)
    stem = floor.verdict_stem(tmp_path, "1,2.5,3", 7)
    assert stem.name == "floor_1_2p5_3_env7" and floor.verdict_stem(tmp_path, "1.2,5,3", 7) != stem
    floor.record_verdict(stem, "1,2.5,3", 7, world, goal, SPEC, verdict)
    run = load_run(stem.parent / f"{stem.name}.mcap")
    assert run.complete and run.meta["scenario"] == floor.SCENARIO and run.meta["env_seed"] == 7
    assert run.meta["settings"]["goal"] == "1,2.5,3" and run.meta["base_hit_step"] == verdict.base_hit_step
    assert run.outcome["outcome"] == ("success" if found else "collision")
    if found:
        assert run.outcome["reach_step"] == 3 and run.outcome["min_true_distance"] == pytest.approx(0.42)
        assert list(run.metrics["step"]) == [0, 1, 2, 3]
        straight_tip = np.array([0.0, 0.0, SPEC.n_links * SPEC.length])
        assert run.metrics["goal_distance"].iloc[0] == pytest.approx(np.linalg.norm(straight_tip - goal), abs=1e-5)
    else:
        assert len(run.metrics) == 0


def test_open_environments_are_per_link_count_and_a_scaled_robots_episodes_are_counted_apart(tmp_path):
    """Open: an environment where no episode of that link count reached the goal (another link count's
    success there does not close it); a robot of other link sizes is counted apart, never judged."""
    from recorder import Recorder

    for links, env, outcome, length in ((4, 0, "collision", 2.0), (4, 1, "success", 2.0), (4, 1, "collision", 2.0),
                                        (5, 1, "collision", 2.0), (5, 0, "success", 2.0), (4, 3, "collision", 1.0)):
        meta = {"scenario": "spheres", "links": links, "env_seed": env, "settings": {"goal": "fixed"},
                "robot": {"length": length}}
        with Recorder(tmp_path / f"L{links}_env{env}_{outcome}_{length}", meta, formats=("mcap",)) as rec:
            rec.log_step(0, 0.0, metrics={"solver_ms": 1.0})
            rec.finish({"outcome": outcome, "steps": 1})
    assert floor.open_environments(tmp_path) == ([(4, "fixed", 0), (5, "fixed", 1)], 1)
    assert floor.verdict_stem(tmp_path, "fixed", 1, 5).name == "floor_fixed_env1_L5"


def test_a_folder_without_sphere_episodes_is_refused_in_one_line(tmp_path, capsys):
    """A folder of other episodes (or none) is a user's mistake, not 'zero open environments': exit 2,
    one line naming the folder, nothing written."""
    from recorder import Recorder

    with Recorder(tmp_path / "cluttered", {"scenario": "cluttered", "links": 4}, formats=("mcap",)) as rec:
        rec.log_step(0, 0.0, metrics={"solver_ms": 1.0})
        rec.finish({"outcome": "stuck", "steps": 1})
    assert floor.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path) in err[0] and "no dynamic-sphere episodes" in err[0]
    assert not (tmp_path / floor.SCENARIO).exists()
