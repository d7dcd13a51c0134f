"""What the controller's stages did at one step, as lines for a recording's log.

:func:`step_events` compares the :class:`ncedf.controller.ControllerState` before and after a
step (and the step's :class:`ncedf.mppi.MPPIInfo`): the safety filter replacing the MPPI action,
the stall escape taking over the temperature, a route planned, followed to its end or given up.
Pure host code: it runs after the step, never inside it.
"""

from __future__ import annotations

from ncedf.controller import ControllerConfig, ControllerState
from ncedf.mppi import MPPIInfo

#: Levels of the lines (the recorder's text-log levels).
INFO, WARNING = "info", "warning"


def _following(state: ControllerState) -> bool:
    return state.route.at < len(state.route.states) - 1


def _route_events(before: ControllerState, after: ControllerState) -> list[tuple[str, str]]:
    if after.route.routes > before.route.routes:
        if _following(after):
            return [(INFO, f"route planned round the obstacle model (plan {after.route.routes}, "
                           f"{len(after.route.states)} states): following it")]
        return [(WARNING, f"route planning found no way round the obstacle model (plan {after.route.routes})")]
    if _following(before) and len(after.route.states) == 0:
        return [(WARNING, f"route given up: its next move was refused {before.route.blocked + 1} steps in a row")]
    if _following(before) and not _following(after):
        return [(INFO, "route followed to its end: MPPI steers again")]
    return []


def step_events(config: ControllerConfig, before: ControllerState, after: ControllerState,
                info: MPPIInfo) -> list[tuple[str, str]]:
    """(level, text) of each event of the step from ``before`` to ``after`` (module docstring)."""
    events = []
    choice = int(info.action_choice)
    if choice != 0:
        events.append((WARNING, f"safety filter: the MPPI action failed its clearance check; executed "
                                f"candidate {choice} (predicted clearance {float(info.action_clearance):.3f} m)"))
    escape = getattr(config.temperature, "escape", None)
    if escape is not None and int(after.mppi.stalled) == escape.after + 1:
        events.append((INFO, f"stall escape: no progress for {escape.after} steps, sharper weights "
                             f"(effective sample size {escape.target:.1%} of the rollouts)"))
    return events + _route_events(before, after)
