"""The paper's published figures (Tables I-IV; RTX 4090), one source for the tables and figures.

From the paper, as transcribed in docs/paper-setups.md and the paper's tables.
"""

from __future__ import annotations

import math

HARDWARE = "NVIDIA RTX 4090 (paper)"

#: Table I: (layers, width) -> (inference ms, MPPI step s, MAE m, RMSE m, MOE m).
TABLE1 = {
    (2, 16): (0.0136, 0.0156, 0.126, 0.167, 0.037), (2, 24): (0.0140, 0.0205, 0.105, 0.137, 0.023),
    (2, 32): (0.0139, 0.0234, 0.089, 0.116, 0.014), (3, 16): (0.0179, 0.0241, 0.040, 0.054, 0.009),
    (3, 24): (0.0181, 0.0337, 0.033, 0.044, 0.006), (3, 32): (0.0178, 0.0415, 0.026, 0.037, 0.004),
    (4, 16): (0.0218, 0.0331, 0.017, 0.024, 0.002), (4, 24): (0.0218, 0.0471, 0.017, 0.025, 0.002),
    (4, 32): (0.0220, 0.0596, 0.016, 0.024, 0.002), (5, 16): (0.0257, 0.0422, 0.015, 0.020, 0.001),
    (5, 24): (0.0264, 0.0603, 0.014, 0.020, 0.001), (5, 32): (0.0262, 0.0772, 0.013, 0.018, 0.001),
}
#: Table II (4 x 16): over-estimation loss used -> (MAE, RMSE, MOE) m.
TABLE2 = {True: (0.017, 0.024, 0.002), False: (0.018, 0.024, 0.011)}
#: Table III (1000 environments): representation -> (success, collision, stuck, MPPI step s).
TABLE3_ENVIRONMENTS = 1000
#: Table III's robot: this many of the paper's links.
TABLE3_LINKS = 4
TABLE3 = {
    "ncedf": (0.986, 0.006, 0.008, 0.006), "spheres": (0.872, 0.005, 0.123, 0.005),
    "pointcloud:1000": (0.942, 0.052, 0.006, 0.062), "pointcloud:5000": (0.984, 0.008, 0.008, 0.284),
}
#: Table III's goal kinds its figures are set beside: its environments are random and its text does not say
#: whether the goal was (the release fixes it); a goal position ``X,Y,Z`` is the user's own.
TABLE3_GOALS = ("fixed", "random")


def table3_robot(links, robot: str) -> bool:
    """Whether sphere episodes are of Table III's robot: its links (``TABLE3_LINKS`` of them), the scene as
    built (``robot``: ``analysis.load.robot_label``, "" for the paper's links at scale 1)."""
    return int(links) == TABLE3_LINKS and robot == ""


def robot_tag(links, robot: str) -> str:
    """", 5 links" (and the robot's label) naming sphere rows of another robot than Table III's, else ""."""
    return "" if table3_robot(links, robot) else f", {int(links)} links" + (f", {robot}" if robot else "")


def table3_reference(shape: str, goal: str) -> tuple[float, float, float, float]:
    """Table III's (success, collision, stuck, MPPI step s) for a representation and goal kind; NaN where the
    paper has no figure."""
    return TABLE3.get(shape, (math.nan,) * 4) if goal in TABLE3_GOALS else (math.nan,) * 4


#: Table IV: links -> (MPPI step s mean, std, reach step).
TABLE4 = {4: (0.0331, 0.0005, 158), 5: (0.0419, 0.0008, 82), 7: (0.0607, 0.0006, 43)}
#: Table IV's scene: observed points per square metre of box face.
TABLE4_DENSITY = 4.0
#: Figs. 5-7: the time steps of the paper's snapshots, per link count (the last is its reach step).
SNAPSHOT_STEPS = {4: (20, 52, 104, 158), 5: (16, 82), 7: (14, 43)}
