"""How recordings look: the colours and sizes both sinks draw with, and the clearance colour map.

Sizes are in scene units (metres), chosen for the robots of this project (links of about 2 m,
tube radius 0.2 m, scenes of about 10 m): thick enough to read at the viewer's default camera.
Colours are RGB(A) bytes; the MCAP sink divides by 255. They are chosen against the dark
background the stored Rerun blueprint sets for the 3D view (`BACKGROUND`), whatever the viewer's theme.

Clearance colour map (`clearance_colors`): a link's clearance d (metres, the exact distance of
the link to the nearest obstacle, negative inside) is mapped piecewise linearly through the
anchors

    d <= 0: red (collision) -> d = m: orange -> d = 2 m: yellow -> d = (2 m + far) / 2: green
    -> d >= far: blue

where m is the recorder's safety margin (`COLOR_MAP_MARGIN` when it has none) and
far = max(FAR_CLEARANCE, 4 m). Values below 0 are red, above far
blue; each channel is interpolated linearly between the anchors and rounded to the nearest byte
(halves up).
NaN (unknown) gets `UNKNOWN_CLEARANCE_COLOR`.
"""

from __future__ import annotations

import math

import numpy as np

#: Clearance (m) from which a link is drawn "far" (blue), unless 4 safety margins are more.
FAR_CLEARANCE = 1.0
#: The colour map's margin (m) for a recorder given no safety margin: a display default only (the
#: paper's delta_s for point clouds); the controller's margin is whatever the caller passes.
COLOR_MAP_MARGIN = 0.05

COLLISION_COLOR = (220, 30, 30)  # red
MARGIN_COLOR = (255, 140, 0)  # orange
NEAR_COLOR = (250, 215, 0)  # yellow
CLEAR_COLOR = (40, 190, 70)  # green
FAR_COLOR = (40, 110, 240)  # blue
UNKNOWN_CLEARANCE_COLOR = (190, 190, 205)  # the robot's colour without clearances

#: The Rerun 3D view's background (a `rerun.blueprint.BackgroundKind` name).
BACKGROUND = "GradientDark"
ROBOT_COLOR = UNKNOWN_CLEARANCE_COLOR
BACKBONE_RADIUS = 0.02
OBSTACLE_COLOR = (230, 80, 50, 110)  # translucent red
OBSTACLE_POINT_COLOR = (245, 245, 245)  # white: apart from the red shapes and the coloured robot
OBSTACLE_POINT_RADIUS = 0.04
PLAN_COLOR = (0, 230, 255)  # bright cyan
PLAN_RADIUS = 0.03  # line strip radius
PLAN_KNOT_RADIUS = 0.06
GOAL_COLOR = (230, 40, 230)  # magenta
GOAL_POINT_RADIUS = 0.06
GOAL_REGION_ALPHA = 110  # the tolerance sphere is translucent
#: A pose goal's approach axis (its z axis) is an arrow ending at the goal, this many tolerances long.
APPROACH_LENGTH = 3.0
APPROACH_RADIUS = 0.03


def clearance_anchors(safety_margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Anchor clearances (5,) in metres and their RGB colours (5, 3) for a safety margin > 0."""
    m = float(safety_margin)
    if not (math.isfinite(m) and m > 0):
        raise ValueError(f"the clearance colour map needs a finite safety margin > 0, got {safety_margin!r}")
    far = max(FAR_CLEARANCE, 4 * m)
    xs = np.array([0.0, m, 2 * m, (2 * m + far) / 2, far])
    colors = np.array([COLLISION_COLOR, MARGIN_COLOR, NEAR_COLOR, CLEAR_COLOR, FAR_COLOR], dtype=np.float64)
    return xs, colors


def clearance_colors(clearance, safety_margin: float) -> np.ndarray:
    """RGB colours (M, 3) uint8 of link clearances (M,) in metres (see the module docstring)."""
    d = np.asarray(clearance, dtype=np.float64)
    xs, colors = clearance_anchors(safety_margin)
    out = np.stack([np.interp(d, xs, colors[:, c]) for c in range(3)], axis=-1)  # clamps outside [0, far]
    out[np.isnan(d)] = UNKNOWN_CLEARANCE_COLOR
    return np.floor(out + 0.5).astype(np.uint8)


def pack_rgba(rgb: np.ndarray, alpha: int = 255) -> np.ndarray:
    """RGB bytes (..., 3) -> packed 0xRRGGBBAA (...,) uint32, the form Rerun takes without conversion."""
    c = np.asarray(rgb, dtype=np.uint32)
    return (c[..., 0] << 24) | (c[..., 1] << 16) | (c[..., 2] << 8) | np.uint32(alpha)
