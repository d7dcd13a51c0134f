"""The flat controller settings of recordings made before the controller was composed of stages.

Those recordings hold one flat dict of 45 fields (their ``mppi`` metadata).
:func:`legacy_config` maps it onto the stages, so that such a recording still
rebuilds its episode. The experiments that were removed with the switchboard
(motion prediction, a filled-in surface model, a held last state, a check
margin, a zero-filled shift, an unlimited action) have no stage: a recording
that used one is refused with a message naming it.

The broad phase's second selection, ``state`` (candidates per rollout state from
groups of the cloud; no preset used it), was removed on 2026-12-07: its fields
(``selection``, ``groups``, ``group_size``) are dropped from a recording of
either form that used the other, ``mean``, and a recording that used it is refused
(:func:`broad_phase_fields`).

Recordings made before 2026-12-07 planned every route of an episode with the
same settings: their route recovery reads back with ``growth`` 1
(:func:`recovery_fields`).

The route planner of recordings made before 2026-12-02 found its goal states
by gradient steps (``goal_step``, 400 ``goal_iterations``); today's planner
finds them by damped least squares, and such a recording rebuilds with today's
goal settings.
"""

from __future__ import annotations

from ncedf.broad_phase import BroadPhase
from ncedf.mppi import MPPIConfig
from ncedf.obstacle_model import ConvexModel
from ncedf.recovery import RouteRecovery
from ncedf.safety import SafetyFilter
from ncedf.sampling import Sampling
from ncedf.temperature import EffectiveSampleSize, Fixed, StallEscape

#: The flat settings' defaults (a recording made before a field existed ran with its default).
DEFAULTS = {
    "temperature": 0.02, "noise_clip": None, "max_points": 512, "broad_phase": True, "k1": 128, "k2": 12,
    "capsule_segments": 2, "selection": "mean", "groups": 32, "group_size": 16, "shift_fill": "last",
    "limit_action": True, "sampling": "project", "noise_smoothing": 0.0, "target_ess": None,
    "safety_check": False, "check_substeps": 4, "check_margin": 0.0, "predict_motion": False, "fill_edge": 0.0,
    "stall_steps": 0, "stall_ess": 0.01, "stall_progress": 0.05, "goal_reach": False, "update_unclipped": False,
    "convex_link": 0.0, "hold_time": 0.0, "sweep_first": False, "follow_executed": False, "route_after": 0,
    "route": {},
}
#: The removed broad-phase selection's fields, and the selection every recording kept may have named.
BROAD_REMOVED, BROAD_SELECTION = ("selection", "groups", "group_size"), "mean"
#: Removed experiments: (field, the value that meant off).
REMOVED = (("predict_motion", False), ("fill_edge", 0.0), ("hold_time", 0.0), ("check_margin", 0.0),
           ("shift_fill", "last"), ("limit_action", True), ("selection", BROAD_SELECTION))
#: The core's fields under their flat names.
CORE = {name: name for name in ("samples", "horizon", "covariance", "alpha_u", "w_goal", "w_coll", "w_state",
                                "w_goal_terminal", "w_coll_terminal", "w_perturbation", "goal_reach",
                                "safety_margin", "epsilon", "control_bound", "dt", "max_points")}
CORE["progress"] = "stall_progress"


def broad_phase_fields(data: dict) -> dict:
    """A recording's broad-phase fields less those of the removed selection (module docstring);
    ValueError where the recording used it."""
    if data.get("selection", BROAD_SELECTION) != BROAD_SELECTION:
        raise ValueError(f"this recording's controller used the broad phase's selection {data['selection']!r}, "
                         "an experiment that was removed")
    return {name: value for name, value in data.items() if name not in BROAD_REMOVED}


def recovery_fields(data: dict) -> dict:
    """A recording's route-recovery fields, ``growth`` 1 where it names none (module docstring)."""
    return {"growth": 1.0, **data}


def legacy_config(flat: dict):
    """The :class:`ncedf.controller.ControllerConfig` of a recording's flat settings."""
    from ncedf.controller import ControllerConfig

    unknown = set(flat) - set(DEFAULTS) - set(CORE.values())
    if unknown:
        raise ValueError(f"unknown controller settings {sorted(unknown)}")
    f = {**DEFAULTS, **flat}
    for name, off in REMOVED:
        if f[name] != off:
            raise ValueError(f"this recording's controller used {name}={f[name]!r}, an experiment that was removed")
    if (f["sweep_first"] or f["follow_executed"]) and not f["safety_check"]:
        raise ValueError("this recording's controller used sweep_first or follow_executed without safety_check, "
                         "which the safety filter stage holds")
    route = dict(f["route"])
    if route.pop("goal_step", None) is not None:  # the gradient planner's goal settings (module docstring)
        route.pop("goal_iterations", None)
    escape = StallEscape(f["stall_steps"], f["stall_ess"]) if f["stall_steps"] else None
    temperature = Fixed(f["temperature"]) if f["target_ess"] is None else EffectiveSampleSize(f["target_ess"], escape)
    broad = BroadPhase(f["k1"], f["k2"], f["capsule_segments"]) if f["broad_phase"] else None
    recovery = (RouteRecovery(**recovery_fields({"after": f["route_after"], "route": route}))
                if f["route_after"] else None)
    return ControllerConfig(
        mppi=MPPIConfig(**{new: f[old] for new, old in CORE.items() if old in f}),
        sampling=Sampling(f["sampling"], f["noise_smoothing"], f["noise_clip"], f["update_unclipped"]),
        temperature=temperature, broad_phase=broad,
        model=ConvexModel(f["convex_link"]) if f["convex_link"] else None,
        safety=SafetyFilter(f["check_substeps"], f["sweep_first"], f["follow_executed"]) if f["safety_check"] else None,
        recovery=recovery)
