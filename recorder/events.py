"""The typed step event the sinks receive, built once from numpy or JAX inputs.

Units: metres, radians, seconds. Every array is converted to numpy exactly once
here (JAX arrays included), checked for shape, and then shared by all sinks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from recorder.schema import STATE_FIELDS, sim_time_ns
from recorder.style import COLOR_MAP_MARGIN, clearance_colors


@dataclass(frozen=True)
class Shapes:
    """True obstacle geometry: spheres (centres (S, 3), radii (S,)), axis-aligned boxes (centres, sizes (B, 3))."""

    sphere_centers: np.ndarray
    sphere_radii: np.ndarray
    box_centers: np.ndarray
    box_sizes: np.ndarray


@dataclass(frozen=True)
class Step:
    """One step as both sinks receive it. Every field but step, sim_time_ns and metrics may be None."""

    step: int
    sim_time_ns: int
    metrics: dict[str, float]
    mesh_vertices: np.ndarray | None = None  # (V, 3) float32
    mesh_triangles: np.ndarray | None = None  # (F, 3) uint32
    backbone: np.ndarray | list[np.ndarray] | None = None  # (M, K, 3) or M polylines (K_i, 3); float32
    obstacle_points: np.ndarray | None = None  # (P, 3) float32
    obstacle_shapes: Shapes | None = None
    goal_position: np.ndarray | None = None  # (3,) float64
    goal_rotation: np.ndarray | None = None  # (3, 3) float64, only when a pose was given
    plan: np.ndarray | None = None  # (H, 3) float32
    state: dict[str, np.ndarray] | None = None  # arc_lengths (M,3), theta (M,), phi (M,), ee_position (3,); float64
    link_clearance: np.ndarray | None = None  # (M,) float64, metres
    link_colors: np.ndarray | None = None  # (M, 3) uint8, `style.clearance_colors` of link_clearance

    @property
    def sim_time(self) -> float:
        return self.sim_time_ns / 1e9


def _points(name: str, value: Any, dtype=np.float32) -> np.ndarray:
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    return arr


def _polylines(value: Any) -> np.ndarray | list[np.ndarray]:
    """(M, K, 3) stays one array (cheaper to log); polylines of different lengths stay a list."""
    try:
        arr = np.asarray(value, dtype=np.float32)
    except ValueError:  # ragged
        return [_points("backbone polyline", line) for line in value]
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"backbone must have shape (M, K, 3) or be a list of (K, 3) polylines, got {arr.shape}")
    return arr


def _shapes(value: Mapping[str, Any]) -> Shapes:
    spheres = value.get("spheres") or {}
    boxes = value.get("boxes") or {}
    centers = _points("obstacle_shapes spheres centers", spheres.get("centers", np.zeros((0, 3))), np.float64)
    radii = np.asarray(spheres.get("radii", np.zeros(0)), dtype=np.float64).reshape(-1)
    box_centers = _points("obstacle_shapes boxes centers", boxes.get("centers", np.zeros((0, 3))), np.float64)
    sizes = _points("obstacle_shapes boxes sizes", boxes.get("sizes", np.zeros((0, 3))), np.float64)
    if radii.shape[0] != centers.shape[0] or sizes.shape[0] != box_centers.shape[0]:
        raise ValueError("obstacle_shapes: one radius per sphere centre and one size per box centre")
    return Shapes(centers, radii, box_centers, sizes)


def make_step(
    step: int,
    sim_time: float,
    metrics: Mapping[str, Any],
    *,
    mesh_vertices=None,
    mesh_triangles=None,
    backbone=None,
    obstacle_points=None,
    obstacle_shapes=None,
    goal=None,
    plan=None,
    state=None,
    link_clearance=None,
    safety_margin: float | None = None,
) -> Step:
    """Convert and check the arguments of `Recorder.log_step` (see there for shapes).

    `safety_margin` (m) sets the colour map of `link_clearance` (`style.COLOR_MAP_MARGIN` if None).
    """
    clean_metrics = {}
    for key, value in metrics.items():
        if key in ("step", "sim_time") or not key.isidentifier():
            raise ValueError(f"metric name {key!r} must be an identifier other than step/sim_time")
        clean_metrics[key] = float(value) if value is not None else float("nan")

    goal_position = goal_rotation = None
    if goal is not None:
        g = np.asarray(goal, dtype=np.float64)
        if g.shape == (3,):
            goal_position = g
        elif g.shape == (4, 4):
            goal_position, goal_rotation = g[:3, 3].copy(), g[:3, :3].copy()
        else:
            raise ValueError(f"goal must be a position (3,) or a pose (4, 4), got {g.shape}")

    clean_state = None
    if state is not None:
        missing = set(STATE_FIELDS) - set(state)
        if missing:
            raise ValueError(f"state is missing {sorted(missing)}")
        clean_state = {k: np.asarray(state[k], dtype=np.float64) for k in STATE_FIELDS}
        m = clean_state["theta"].shape[0]
        expected = {"arc_lengths": (m, 3), "theta": (m,), "phi": (m,), "ee_position": (3,)}
        for k, shape in expected.items():
            if clean_state[k].shape != shape:
                raise ValueError(f"state {k} must have shape {shape}, got {clean_state[k].shape}")

    triangles = None
    if mesh_triangles is not None:
        triangles = np.asarray(mesh_triangles, dtype=np.uint32)
        if triangles.ndim != 2 or triangles.shape[1] != 3:
            raise ValueError(f"mesh_triangles must have shape (F, 3), got {triangles.shape}")

    mesh = None if mesh_vertices is None else _points("mesh_vertices", mesh_vertices)
    lines = None if backbone is None else _polylines(backbone)
    clearance = colors = None
    if link_clearance is not None:
        clearance = _link_clearance(link_clearance, mesh, lines, clean_state)
        colors = clearance_colors(clearance, COLOR_MAP_MARGIN if safety_margin is None else safety_margin)

    return Step(
        step=int(step),
        sim_time_ns=sim_time_ns(sim_time),
        metrics=clean_metrics,
        mesh_vertices=mesh,
        mesh_triangles=triangles,
        backbone=lines,
        obstacle_points=None if obstacle_points is None else _points("obstacle_points", obstacle_points),
        obstacle_shapes=None if obstacle_shapes is None else _shapes(obstacle_shapes),
        goal_position=goal_position,
        goal_rotation=goal_rotation,
        plan=None if plan is None else _points("plan", plan),
        state=clean_state,
        link_clearance=clearance,
        link_colors=colors,
    )


def _link_clearance(value: Any, mesh: np.ndarray | None, lines, state: dict | None) -> np.ndarray:
    """(M,) clearances, checked against the links of the mesh (V = M x vertices per link), backbone and state."""
    d = np.asarray(value, dtype=np.float64)
    if d.ndim != 1 or d.size == 0:
        raise ValueError(f"link_clearance must have shape (M,) with M >= 1 links, got {d.shape}")
    m = d.shape[0]
    if mesh is not None and mesh.shape[0] % m:
        raise ValueError(f"mesh_vertices ({mesh.shape[0]}) must split into {m} links of equal vertex counts "
                         "to colour them by link_clearance")
    if lines is not None and len(lines) != m:
        raise ValueError(f"backbone has {len(lines)} polylines, link_clearance {m} links: give one per link")
    if state is not None and state["theta"].shape[0] != m:
        raise ValueError(f"link_clearance has {m} links, the state {state['theta'].shape[0]}")
    return d
