"""The stages' events of a step (``ncedf.events``), from states before and after it."""

import jax
import numpy as np
import pytest

from ncedf.controller import Controller, ControllerConfig
from ncedf.events import INFO, WARNING, step_events
from ncedf.mppi import MPPIInfo
from ncedf.robot import RobotSpec
from ncedf.shapes import make_shape
from ncedf.temperature import EffectiveSampleSize, StallEscape

SPEC = RobotSpec(2)
ESCAPE = StallEscape(after=30, target=0.005)
CONFIG = ControllerConfig(temperature=EffectiveSampleSize(0.02, ESCAPE))


@pytest.fixture(scope="module")
def state():
    return Controller(SPEC, make_shape("exact", SPEC), CONFIG).init(jax.random.PRNGKey(0))


def info(choice=0, clearance=float("nan")):
    fields = {name: np.float32(0.0) for name in MPPIInfo._fields}
    return MPPIInfo(**{**fields, "action_choice": np.int32(choice), "action_clearance": np.float32(clearance)})


def with_route(state, count, at, routes, blocked=0):
    states = np.zeros((count, SPEC.n_links, 3), np.float32)
    return state._replace(route=state.route._replace(states=states, at=at, routes=routes, blocked=blocked))


def stalled(state, steps):
    return state._replace(mppi=state.mppi._replace(stalled=np.int32(steps)))


def test_a_quiet_step_has_no_events(state):
    assert step_events(CONFIG, state, state, info()) == []


def test_the_safety_filter_replacing_the_action_is_a_warning_with_its_clearance(state):
    ((level, text),) = step_events(CONFIG, state, state, info(2, 0.0712))
    assert level == WARNING and "candidate 2" in text and "0.071 m" in text


def test_the_stall_escape_is_told_once_when_it_takes_over(state):
    told = [steps for steps in range(25, 40) if step_events(CONFIG, state, stalled(state, steps), info())]
    assert told == [ESCAPE.after + 1]
    ((level, text),) = step_events(CONFIG, state, stalled(state, ESCAPE.after + 1), info())
    assert level == INFO and "30 steps" in text and "0.5%" in text
    assert step_events(ControllerConfig(), state, stalled(state, ESCAPE.after + 1), info()) == []  # no escape


def test_a_route_planned_found_followed_and_given_up(state):
    planned = step_events(CONFIG, state, with_route(state, 5, 0, 1), info())
    assert planned == [(INFO, "route planned round the obstacle model (plan 1, 5 states): following it")]
    ((level, text),) = step_events(CONFIG, with_route(state, 0, 0, 1), with_route(state, 0, 0, 2), info())
    assert level == WARNING and "no way round" in text and "plan 2" in text
    ((level, text),) = step_events(CONFIG, with_route(state, 5, 3, 1), with_route(state, 5, 4, 1), info())
    assert level == INFO and "to its end" in text
    ((level, text),) = step_events(CONFIG, with_route(state, 5, 2, 1, blocked=29), with_route(state, 0, 0, 1), info())
    assert level == WARNING and "30 steps in a row" in text
    assert step_events(CONFIG, with_route(state, 5, 1, 1), with_route(state, 5, 2, 1), info()) == []
