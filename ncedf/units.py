"""The robot's unit of length: what makes a robot and its world scaled together behave the same.

Every length and speed of the controller's configuration (safety margin, rate bound, sampling
covariance, the obstacle models' and routes' clearances, ...) is given for a robot whose links are
``REFERENCE_LENGTH`` long, the paper's. A robot whose links are ``L`` long is controlled in units of
``unit(spec) = L / REFERENCE_LENGTH`` metres: the controller sees the robot, its goal and the
observed points divided by the unit (:func:`to_reference`) and multiplies its rates and reported
distances by it. The N-CEDF's network works in the same units (``ncedf.model``), so one recipe
trains robots of any size.
"""

from __future__ import annotations

from ncedf.robot import RobotSpec

#: The link length the controller's constants are given for (the paper's robot), m.
REFERENCE_LENGTH = 2.0


def unit(spec: RobotSpec) -> float:
    """Metres per reference unit for ``spec``'s robot: its link length over ``REFERENCE_LENGTH``."""
    return spec.length / REFERENCE_LENGTH


def to_reference(spec: RobotSpec) -> RobotSpec:
    """``spec`` scaled to links of ``REFERENCE_LENGTH`` (the robot in reference units)."""
    return spec.scaled(REFERENCE_LENGTH / spec.length)
