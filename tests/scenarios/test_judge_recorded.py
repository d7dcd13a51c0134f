"""The judge against its own records: the committed Table IV episode (results/closed_loop) judged
again step by step gives the recorded exact distances to the last float, so the rebuilt judge
(scenarios.judge, scenarios.truth) judges the paper's boxes and spheres as the one that recorded it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ncedf.robot import RobotSpec
from recorder.read import load_run
from scenarios import cluttered
from scenarios.judge import judge_step

RECORDING = Path(__file__).parents[2] / "results" / "closed_loop" / "cluttered_L7_ours_s0.mcap"


def test_the_recorded_cluttered_episode_judges_the_same():
    run = load_run(RECORDING)
    links = int(run.meta["links"])
    arcs = run.state[[f"arc_{i}_{j}" for i in range(1, links + 1) for j in (1, 2, 3)]].to_numpy(np.float64)
    arcs = arcs.reshape(-1, links, 3)
    times = run.state.sim_time.to_numpy()
    world, spec = cluttered.make_world(), RobotSpec(links)
    judged = [judge_step(world, spec, a, b, t0, t1 - t0).min_distance
              for a, b, t0, t1 in zip(arcs[:-1], arcs[1:], times[:-1], times[1:])]
    recorded = run.metrics.true_min_distance.to_numpy()[:len(judged)]
    assert len(judged) == 12
    np.testing.assert_array_equal(judged, recorded)
