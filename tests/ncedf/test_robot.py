"""Tests of ncedf.robot: RobotSpec, states, paper eq. (1), PCC link transform, FK (eq. 4).

Every expected value is computed independently in the test (numpy closed forms
written from the paper, elementary rotation matrices, numerical integration of
the backbone, finite differences, brute force), never copied from the code.
"""

from __future__ import annotations

import dataclasses
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.robot import (
    InvalidStateError,
    RobotSpec,
    arc_lengths_to_config,
    backbone_points,
    bending_vector,
    config_to_arc_lengths,
    end_effector_pose,
    forward_kinematics,
    frame_to_world,
    link_transform,
    points_from_link_frames,
    points_in_link_frames,
    project_state,
    sample_arc_lengths,
    state_violation,
    validate_state,
    world_to_frame,
)

SPEC1 = RobotSpec(1)
SPEC4 = RobotSpec(4)

# Jitted entry points (spec static), shared by all tests: each compiles once per
# shape and dtype (float32 by default, float64 under jax.enable_x64) and is then
# reused, instead of eager mode compiling and dispatching every jax op separately.
eq1 = jax.jit(arc_lengths_to_config, static_argnums=1)
eq1_inverse = jax.jit(config_to_arc_lengths, static_argnums=2)
link_tf = jax.jit(link_transform, static_argnums=2)
fk = jax.jit(forward_kinematics, static_argnums=1)
ee_pose = jax.jit(end_effector_pose, static_argnums=1)
sample = jax.jit(sample_arc_lengths, static_argnums=(1, 2))


# ----------------------------------------------------------------------------
# independent references (numpy)


def eq1_numpy(arc: np.ndarray, r: float):
    """Paper eq. (1), written from the paper's text."""
    l1, l2, l3 = arc[..., 0], arc[..., 1], arc[..., 2]
    theta = 2.0 * np.sqrt(l1**2 + l2**2 + l3**2 - l1 * l2 - l1 * l3 - l2 * l3) / (3.0 * r)
    phi = np.arctan2(np.sqrt(3.0) * (l2 - l3), l2 + l3 - 2.0 * l1)
    return theta, phi


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def link_transform_numpy(theta: float, phi: float, length: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot_z(phi) @ rot_y(theta) @ rot_z(-phi)
    if theta == 0.0:
        T[:3, 3] = [0.0, 0.0, length]
    else:
        rho = length / theta
        one_minus_cos = 2.0 * np.sin(theta / 2) ** 2  # = 1 - cos(theta), without cancellation
        T[:3, 3] = [
            rho * one_minus_cos * np.cos(phi),
            rho * one_minus_cos * np.sin(phi),
            rho * np.sin(theta),
        ]
    return T


def integrate_backbone(theta: float, phi: float, length: float, steps: int = 2000):
    """RK4 on dp/ds = R e_z, dR/ds = R [w]x with body angular rate w = kappa (-sin phi, cos phi, 0)."""
    kappa = theta / length
    w = kappa * np.array([-np.sin(phi), np.cos(phi), 0.0])
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    ez = np.array([0.0, 0.0, 1.0])

    def f(state):
        R = state[:9].reshape(3, 3)
        return np.concatenate([(R @ W).ravel(), R @ ez])

    y = np.concatenate([np.eye(3).ravel(), np.zeros(3)])
    h = length / steps
    for _ in range(steps):
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return y[9:], y[:9].reshape(3, 3)


def circ_diff(a, b):
    """Signed difference of angles, wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))


def brute_max_bend(spec: RobotSpec, n: int = 200_001) -> float:
    """Largest theta over phi such that every chamber stays within the limits (dense phi scan)."""
    phi = np.linspace(-np.pi, np.pi, n)
    best = np.full(n, np.inf)
    for j in range(3):
        c = np.cos(phi + 2 * np.pi * j / 3)  # l_j = L - r theta c
        with np.errstate(divide="ignore"):
            lim = np.where(
                c > 0,
                (spec.length - spec.l_min) / (spec.radius * c),
                (spec.l_max - spec.length) / (spec.radius * -c),
            )
        best = np.minimum(best, np.where(np.abs(c) < 1e-15, np.inf, lim))
    return float(best.max())


# ----------------------------------------------------------------------------
# RobotSpec


def test_spec_defaults_and_frozen():
    spec = RobotSpec(3)
    assert (spec.n_links, spec.length, spec.radius, spec.l_min, spec.l_max) == (3, 2.0, 0.2, 1.6, 2.4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.length = 3.0  # type: ignore[misc]
    assert RobotSpec(3) == spec and hash(RobotSpec(3)) == hash(spec)
    RobotSpec(np.int64(2))  # numpy integers are integers


@pytest.mark.parametrize(
    "kwargs, shown",
    [
        (dict(n_links=0), "0"),
        (dict(n_links=-2), "-2"),
        (dict(n_links=2.5), "2.5"),
        (dict(n_links=True), "True"),
        (dict(n_links="3"), "'3'"),
        (dict(n_links=2, radius=0.0), "0.0"),
        (dict(n_links=2, radius=-0.1), "-0.1"),
        (dict(n_links=2, radius=float("nan")), "nan"),
        (dict(n_links=2, length=float("inf")), "inf"),
        (dict(n_links=2, l_min=float("nan")), "nan"),
        (dict(n_links=2, l_max=float("-inf")), "-inf"),
        (dict(n_links=2, l_min=2.0), "l_min=2.0"),
        (dict(n_links=2, l_min=2.1), "l_min=2.1"),
        (dict(n_links=2, l_max=2.0), "l_max=2.0"),
        (dict(n_links=2, l_max=1.9), "l_max=1.9"),
        (dict(n_links=2, length=2.5), "length=2.5"),
        (dict(n_links=2, length=1.0), "length=1.0"),
        (dict(n_links=2, length="2"), "'2'"),
    ],
)
def test_spec_validation_names_bad_value(kwargs, shown):
    with pytest.raises(ValueError, match=re.escape(shown)):
        RobotSpec(**kwargs)


@pytest.mark.parametrize(
    "spec",
    [
        RobotSpec(1),
        RobotSpec(2, length=1.0, radius=0.05, l_min=0.9, l_max=1.1),
        RobotSpec(1, l_min=1.8, l_max=2.4),  # asymmetric limits
        RobotSpec(1, l_min=1.2, l_max=2.1),  # asymmetric the other way
        RobotSpec(1, l_min=1.9, l_max=2.5),  # 2 (L - l_min) < l_max - L
    ],
)
def test_max_bend_matches_dense_scan(spec):
    assert spec.max_bend() == pytest.approx(brute_max_bend(spec), rel=1e-5)


def test_straight_state():
    s = np.asarray(SPEC4.straight_state())
    assert s.shape == (4, 3)
    np.testing.assert_array_equal(s, 2.0)


# ----------------------------------------------------------------------------
# validate_state


def test_validate_state_accepts_valid_states():
    arc = np.asarray(sample(jax.random.key(0), SPEC4, (4,)), dtype=np.float64)
    out = validate_state(arc, SPEC4)
    assert out.dtype == np.float64 and out.shape == (4, 3)
    np.testing.assert_allclose(out, arc)
    validate_state(SPEC4.straight_state(), SPEC4)
    # limits themselves are valid
    validate_state([[1.6, 2.4, 2.0]], SPEC1)
    validate_state([[2.4, 2.4, 1.2 + 1e-9]], RobotSpec(1, l_min=1.2))


@pytest.mark.parametrize(
    "arc, shown",
    [
        ([[1.5, 2.25, 2.25]], "1.5"),  # below l_min, sums to 3L
        ([[2.5, 1.75, 1.75]], "2.5"),  # above l_max, sums to 3L
        ([[2.1, 2.1, 2.1]], "6.3"),  # within limits, sum 6.3 != 6
        ([[1.9, 1.9, 2.0]], "5.8"),
        ([[2.0, 2.0, 2.0], [2.0, 2.0, 2.0]], "(2, 3)"),  # wrong shape for 1 link
        ([2.0, 2.0, 2.0], "(3,)"),
        ([[2.0, 2.0, 2.0, 0.0]], "(1, 4)"),
        ([[float("nan"), 2.0, 2.0]], "NaN"),
        ([[float("inf"), 2.0, 2.0]], "inf"),
    ],
)
def test_validate_state_rejects_and_names_value(arc, shown):
    with pytest.raises(InvalidStateError, match=re.escape(shown)) as info:
        validate_state(arc, SPEC1)
    assert isinstance(info.value, ValueError)


def test_validate_state_names_the_bad_link_sum():
    arc = np.full((3, 3), 2.0)
    arc[1] = [2.2, 2.2, 2.2]
    with pytest.raises(InvalidStateError, match="6.6"):
        validate_state(arc, RobotSpec(3))


def test_sample_arc_lengths_are_valid_and_cover_range():
    arc = np.asarray(sample(jax.random.key(1), SPEC1, (5000,)), dtype=np.float64)
    assert arc.shape == (5000, 3)
    assert arc.min() >= SPEC1.l_min - 1e-6 and arc.max() <= SPEC1.l_max + 1e-6
    np.testing.assert_allclose(arc.sum(-1), 6.0, atol=3e-6)
    for row in arc[:50]:
        validate_state(row[None], SPEC1)
    # every chamber explores the whole range
    for j in range(3):
        assert arc[:, j].min() < 1.65 and arc[:, j].max() > 2.35
    # l1 uniform in the limits (paper Sec. IV-B): mean and quartiles
    assert np.mean(arc[:, 0]) == pytest.approx(2.0, abs=0.02)
    np.testing.assert_allclose(np.quantile(arc[:, 0], [0.25, 0.75]), [1.8, 2.2], atol=0.025)
    # batched shapes (traced only: the shape needs no compilation)
    assert jax.eval_shape(lambda k: sample_arc_lengths(k, SPEC1, (2, 3)), jax.random.key(2)).shape == (2, 3, 3)
    assert jax.eval_shape(lambda k: sample_arc_lengths(k, SPEC1), jax.random.key(2)).shape == (3,)


# ----------------------------------------------------------------------------
# paper eq. (1) and its inverse


def test_eq1_against_numpy_formula():
    with jax.enable_x64(True):
        arc = np.asarray(sample(jax.random.key(3), SPEC1, (5000,)))  # the shape test_round_trip_* compiles too
        theta, phi = eq1(jnp.asarray(arc), SPEC1)
        theta, phi = np.asarray(theta), np.asarray(phi)
    t_ref, p_ref = eq1_numpy(arc, SPEC1.radius)
    np.testing.assert_allclose(theta, t_ref, atol=1e-9)
    ok = t_ref > 1e-6
    np.testing.assert_allclose(circ_diff(phi[ok], p_ref[ok]), 0.0, atol=1e-9)
    assert np.all(theta >= 0) and np.all(theta <= np.pi)
    assert np.all(phi >= -np.pi) and np.all(phi < np.pi)


def test_eq1_float32_default_and_other_radius():
    spec = RobotSpec(1, length=1.0, radius=0.05, l_min=0.9, l_max=1.1)
    arc = np.asarray(sample(jax.random.key(4), spec, (500,)), dtype=np.float64)
    theta, phi = eq1(jnp.asarray(arc, jnp.float32), spec)
    t_ref, p_ref = eq1_numpy(arc, spec.radius)
    np.testing.assert_allclose(np.asarray(theta), t_ref, atol=5e-5)
    ok = t_ref > 1e-2
    np.testing.assert_allclose(circ_diff(np.asarray(phi)[ok], p_ref[ok]), 0.0, atol=5e-4)


def test_eq1_hand_cases():
    r, L = SPEC1.radius, SPEC1.length
    d = 0.1
    cases = [
        # chamber 1 (at +x) shortened -> bends towards +x
        ([L - 2 * d, L + d, L + d], 3 * d / r / 1.5, 0.0),
        # chamber 1 lengthened, l2 == l3 -> phi = pi, which must be reported as -pi
        ([L + 2 * d, L - d, L - d], 3 * d / r / 1.5, -np.pi),
        # l1 = L, l2 > l3 -> phi = +pi/2
        ([L, L + d, L - d], 2 * d / (np.sqrt(3) * r), np.pi / 2),
        ([L, L - d, L + d], 2 * d / (np.sqrt(3) * r), -np.pi / 2),
        ([L, L, L], 0.0, None),
    ]
    for arc, t_ref, p_ref in cases:
        theta, phi = eq1(jnp.asarray(arc), SPEC1)
        assert float(theta) == pytest.approx(t_ref, abs=1e-5)
        # float32: the representable -pi is -np.float32(np.pi)
        assert -np.float32(np.pi) <= phi < np.float32(np.pi)
        if p_ref is not None:
            assert float(phi) == pytest.approx(p_ref, abs=1e-5)
        else:
            assert np.isfinite(float(phi))


def test_config_to_arc_lengths_formula_and_sum():
    with jax.enable_x64(True):
        th = np.linspace(0, 2.0, 7)
        ph = np.linspace(-np.pi, np.pi, 9, endpoint=False)
        T, P = np.meshgrid(th, ph, indexing="ij")
        arc = np.asarray(eq1_inverse(jnp.asarray(T), jnp.asarray(P), SPEC1))
    assert arc.shape == (7, 9, 3)
    np.testing.assert_allclose(arc.sum(-1), 3 * SPEC1.length, atol=1e-12)
    # inverse of eq. (1): chamber j's length is L minus r theta times the
    # projection of the bending direction on the chamber direction (-2 pi j / 3)
    for j in range(3):
        ref = SPEC1.length - SPEC1.radius * T * np.cos(P + 2 * np.pi * j / 3)
        np.testing.assert_allclose(arc[..., j], ref, atol=1e-12)


def test_round_trip_arc_config_arc_sampled():
    with jax.enable_x64(True):
        arc = sample(jax.random.key(5), SPEC1, (5000,))
        theta, phi = eq1(arc, SPEC1)
        back = eq1_inverse(theta, phi, SPEC1)
        np.testing.assert_allclose(np.asarray(back), np.asarray(arc), atol=1e-6)
    # float32 (the default dtype) still meets 1e-6 relative to the arc lengths' scale
    arc32 = sample(jax.random.key(5), SPEC1, (5000,))
    back32 = eq1_inverse(*eq1(arc32, SPEC1), SPEC1)
    np.testing.assert_allclose(np.asarray(back32), np.asarray(arc32), atol=2e-6)


def test_round_trip_config_arc_config_grid():
    with jax.enable_x64(True):
        th = np.linspace(0.0, SPEC1.max_bend(), 61)
        ph = np.linspace(-np.pi, np.pi, 73, endpoint=False)
        T, P = np.meshgrid(th, ph, indexing="ij")
        arc = eq1_inverse(jnp.asarray(T), jnp.asarray(P), SPEC1)
        theta, phi = (np.asarray(x) for x in eq1(arc, SPEC1))
        back = np.asarray(eq1_inverse(jnp.asarray(theta), jnp.asarray(phi), SPEC1))
    np.testing.assert_allclose(back, np.asarray(arc), atol=1e-6)
    np.testing.assert_allclose(theta, T, atol=1e-9)
    ok = T > 0
    np.testing.assert_allclose(circ_diff(phi[ok], P[ok]), 0.0, atol=1e-9)
    assert np.all(phi >= -np.pi) and np.all(phi < np.pi)
    # theta = 0: all arc lengths L
    np.testing.assert_allclose(np.asarray(arc)[0], SPEC1.length, atol=1e-15)
    np.testing.assert_array_equal(theta[0], 0.0)


def test_round_trip_whole_valid_range_boundary():
    """States on the boundary of the valid set (some chamber at a limit) round-trip too."""
    with jax.enable_x64(True):
        phi = np.linspace(-np.pi, np.pi, 720, endpoint=False)
        c = np.stack([np.cos(phi + 2 * np.pi * j / 3) for j in range(3)], -1)
        lim = 0.4 / (0.2 * np.maximum(np.abs(c), 1e-300))  # symmetric limits: |r theta c| <= 0.4
        theta_edge = lim.min(-1)  # largest valid theta for each phi
        arc = np.asarray(eq1_inverse(jnp.asarray(theta_edge), jnp.asarray(phi), SPEC1))
        assert arc.min() >= 1.6 - 1e-12 and arc.max() <= 2.4 + 1e-12
        t, p = eq1(jnp.asarray(arc), SPEC1)
        back = np.asarray(eq1_inverse(t, p, SPEC1))
    np.testing.assert_allclose(back, arc, atol=1e-6)
    assert theta_edge.max() == pytest.approx(SPEC1.max_bend(), rel=1e-4)


# ----------------------------------------------------------------------------
# link transform


def _configs():
    rng = np.random.default_rng(6)
    out = [(0.0, 0.0), (0.0, 1.0), (1e-6, 0.4), (0.5, 0.0), (0.5, np.pi / 2), (2.3, -np.pi), (np.pi - 1e-3, 2.0)]
    out += [(float(t), float(p)) for t, p in zip(rng.uniform(0, 2.31, 12), rng.uniform(-np.pi, np.pi, 12))]
    return out


@pytest.mark.parametrize("theta, phi", _configs())
def test_link_transform_matches_elementary_rotations(theta, phi):
    with jax.enable_x64(True):
        T = np.asarray(link_tf(jnp.asarray(theta), jnp.asarray(phi), SPEC1))
    ref = link_transform_numpy(theta, phi, SPEC1.length)
    np.testing.assert_allclose(T, ref, atol=1e-10)
    # proper rigid transform
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


@pytest.mark.parametrize("theta, phi", [(0.0, 0.0), (0.3, 0.7), (1.2, -2.0), (2.3, 3.0), (3.0, -0.5)])
def test_link_transform_matches_integrated_backbone(theta, phi):
    with jax.enable_x64(True):
        T = np.asarray(link_tf(jnp.asarray(theta), jnp.asarray(phi), SPEC1))
    p, R = integrate_backbone(theta, phi, SPEC1.length)
    np.testing.assert_allclose(T[:3, 3], p, atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], R[:, 2], atol=1e-9)  # end tangent
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-9)
    # the end point is at chord length 2 rho sin(theta / 2) from the base
    chord = SPEC1.length * (np.sinc(theta / 2 / np.pi))
    assert np.linalg.norm(T[:3, 3]) == pytest.approx(chord, abs=1e-9)


def test_link_transform_float32_and_batched():
    rng = np.random.default_rng(7)
    th = rng.uniform(0, 2.3, (4, 5))
    ph = rng.uniform(-np.pi, np.pi, (4, 5))
    T = np.asarray(link_tf(jnp.asarray(th, jnp.float32), jnp.asarray(ph, jnp.float32), SPEC1))
    assert T.shape == (4, 5, 4, 4) and T.dtype == np.float32
    for i in range(4):
        for j in range(5):
            np.testing.assert_allclose(T[i, j], link_transform_numpy(th[i, j], ph[i, j], 2.0), atol=1e-6)


@pytest.mark.parametrize("theta", [1e-7, 1e-5, 1e-4, 1e-3, 9.9999e-3, 1e-2, 1.00001e-2, 2e-2, 0.1])
def test_link_transform_small_theta_float32_continuity(theta):
    """No float32 blow-up near theta = 0 (series / closed-form switch included)."""
    T = np.asarray(link_tf(jnp.float32(theta), jnp.float32(0.7), SPEC1))
    ref = link_transform_numpy(theta, 0.7, SPEC1.length)
    np.testing.assert_allclose(T, ref, atol=1e-6)
    straight = link_transform_numpy(0.0, 0.0, SPEC1.length)
    # Lipschitz in theta: the end moves at most L theta / 2 + O(theta^2), rotates by theta
    assert np.max(np.abs(T[:3, 3] - straight[:3, 3])) <= SPEC1.length * theta / 2 * 1.01 + 5e-6


# ----------------------------------------------------------------------------
# forward kinematics


def arc_for(theta, phi, spec):
    """Arc lengths for (theta, phi): chamber j sits at angle -2 pi j / 3 (what eq. (1) implies)."""
    return [spec.length - spec.radius * theta * math.cos(phi + 2 * math.pi * j / 3) for j in range(3)]


def test_fk_straight_state():
    frames = np.asarray(fk(SPEC4.straight_state(), SPEC4))
    assert frames.shape == (5, 4, 4)
    for i in range(5):
        ref = np.eye(4)
        ref[2, 3] = i * SPEC4.length
        np.testing.assert_allclose(frames[i], ref, atol=1e-6)
    np.testing.assert_allclose(np.asarray(ee_pose(SPEC4.straight_state(), SPEC4))[:3, 3], [0, 0, 8.0], atol=1e-6)


def test_fk_two_links_bending_in_x_then_y_by_hand():
    spec = RobotSpec(2)
    L, r = spec.length, spec.radius
    t1, t2 = 1.0, 0.8
    # Link 1 bends towards +x (eq. 1: phi = atan2(0, 3 r t1) = 0, theta = t1).
    # Link 2 bends towards +y of its own base frame (eq. 1: l1 = L, l2 - l3 > 0
    # gives phi = +pi/2; theta = 2 sqrt(3 e^2) / (3 r) = t2 for e = sqrt(3) r t2 / 2).
    e = np.sqrt(3) * r * t2 / 2
    arc = np.array([[L - r * t1, L + r * t1 / 2, L + r * t1 / 2], [L, L + e, L - e]])
    t_chk, p_chk = eq1_numpy(arc, r)
    np.testing.assert_allclose(t_chk, [t1, t2], atol=1e-12)
    np.testing.assert_allclose(p_chk, [0.0, np.pi / 2], atol=1e-12)
    with jax.enable_x64(True):
        frames = np.asarray(fk(jnp.asarray(arc), spec))
    rho1, rho2 = L / t1, L / t2
    c1, s1, c2, s2 = np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2)
    p1 = np.array([rho1 * (1 - c1), 0.0, rho1 * s1])
    # link 2 in its own frame ends at (0, rho2 (1 - c2), rho2 s2); map by Ry(t1), add p1
    ee = np.array([rho1 * (1 - c1) + s1 * rho2 * s2, rho2 * (1 - c2), rho1 * s1 + c1 * rho2 * s2])
    np.testing.assert_allclose(frames[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(frames[1][:3, 3], p1, atol=1e-9)
    np.testing.assert_allclose(frames[1][:3, :3], rot_y(t1), atol=1e-9)
    np.testing.assert_allclose(frames[2][:3, 3], ee, atol=1e-9)
    # bending about -x of link 2's base frame: R_ee = Ry(t1) Rx(-t2)
    np.testing.assert_allclose(frames[2][:3, :3], rot_y(t1) @ rot_x(-t2), atol=1e-9)
    # the ee tangent, by hand
    np.testing.assert_allclose(frames[2][:3, 2], [s1 * c2, s2, c1 * c2], atol=1e-9)


def test_fk_is_product_of_link_transforms():
    spec = RobotSpec(5)
    with jax.enable_x64(True):
        arc = np.asarray(sample(jax.random.key(8), spec, (5,)))
        frames = np.asarray(fk(jnp.asarray(arc), spec))
    theta, phi = eq1_numpy(arc, spec.radius)
    acc = np.eye(4)
    np.testing.assert_allclose(frames[0], acc, atol=1e-12)
    for i in range(5):
        acc = acc @ link_transform_numpy(theta[i], phi[i], spec.length)
        np.testing.assert_allclose(frames[i + 1], acc, atol=1e-9)
    for F in frames:
        R = F[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-10)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-10)
    # end-effector pose is the last frame
    with jax.enable_x64(True):
        np.testing.assert_allclose(np.asarray(ee_pose(jnp.asarray(arc), spec)), frames[-1], atol=1e-12)


def test_fk_matches_integrated_chain():
    """The whole robot backbone integrated as one curve with piecewise-constant curvature."""
    spec = RobotSpec(3)
    with jax.enable_x64(True):
        arc = np.asarray(sample(jax.random.key(9), spec, (3,)))
        frames = np.asarray(fk(jnp.asarray(arc), spec))
    theta, phi = eq1_numpy(arc, spec.radius)
    R_acc, p_acc = np.eye(3), np.zeros(3)
    for i in range(3):
        p, R = integrate_backbone(theta[i], phi[i], spec.length, steps=1000)
        p_acc = p_acc + R_acc @ p
        R_acc = R_acc @ R
        np.testing.assert_allclose(frames[i + 1][:3, 3], p_acc, atol=1e-8)
        np.testing.assert_allclose(frames[i + 1][:3, :3], R_acc, atol=1e-8)
    # backbone length bounds the reach
    assert np.linalg.norm(frames[-1][:3, 3]) <= 3 * spec.length


def test_backbone_points_match_the_integrated_backbone_in_the_world():
    """Each link's backbone point at arc length u L, integrated as a partial link (bend u theta over
    u L) and carried into the world by the chain of frames before it; batched over two states."""
    spec = RobotSpec(3)
    fractions = np.array([0.0, 0.05, 0.5, 0.93, 1.0])
    with jax.enable_x64(True):
        arcs = np.array(sample(jax.random.key(11), spec, (2, 3)))
        arcs[1, 0] = spec.length  # a straight first link
        frames = np.asarray(fk(jnp.asarray(arcs), spec))
        got = np.asarray(backbone_points(bending_vector(jnp.asarray(arcs), spec), jnp.asarray(frames[:, :-1]),
                                         jnp.asarray(fractions), spec.length))
    assert got.shape == (2, 3, len(fractions), 3)
    for b in range(2):
        theta, phi = eq1_numpy(arcs[b], spec.radius)
        for i in range(3):
            base = frames[b, i]
            for k, u in enumerate(fractions):
                local = integrate_backbone(u * theta[i], phi[i], u * spec.length, steps=400)[0] if u else np.zeros(3)
                np.testing.assert_allclose(got[b, i, k], base[:3, :3] @ local + base[:3, 3], atol=1e-8)
            np.testing.assert_allclose(got[b, i, -1], frames[b, i + 1][:3, 3], atol=1e-12)  # u = 1: the next frame


def test_fk_batched_leading_dims():
    spec = RobotSpec(3)
    arc = sample(jax.random.key(10), spec, (2, 4, 3))  # (2, 4, M=3, 3)
    frames = np.asarray(fk(arc, spec))
    assert frames.shape == (2, 4, 4, 4, 4)
    for i in range(2):
        for j in range(4):
            np.testing.assert_allclose(frames[i, j], np.asarray(fk(arc[i, j], spec)), atol=1e-6)
    ee = np.asarray(ee_pose(arc, spec))
    assert ee.shape == (2, 4, 4, 4)
    np.testing.assert_allclose(ee, frames[:, :, -1], atol=1e-6)


# ----------------------------------------------------------------------------
# gradients at theta = 0 (the straight initial state)


def _central_fd(f, x, h=1e-6):
    """Central differences of a function that accepts a leading batch dimension: (y_shape + x_shape)."""
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    eye = np.eye(n).reshape((n,) + x.shape) * h
    ys = np.asarray(f(jnp.asarray(np.concatenate([x + eye, x - eye]))))
    d = (ys[:n] - ys[n:]) / (2 * h)  # (n,) + y_shape
    return np.moveaxis(d, 0, -1).reshape(d.shape[1:] + x.shape)


def test_fk_gradients_at_straight_are_finite_and_match_fd():
    spec = RobotSpec(2)
    with jax.enable_x64(True):
        fk2 = lambda a: forward_kinematics(a, spec)
        straight = np.asarray(spec.straight_state())
        mixed = straight.copy()  # link 2 straight, link 1 bent
        mixed[0] = arc_for(0.6, 0.3, spec)
        xs = jnp.asarray(np.stack([straight, mixed]))
        # reverse and forward mode in one compiled function
        jr, jf = jax.jit(jax.vmap(lambda a: (jax.jacrev(fk2)(a), jax.jacfwd(fk2)(a))))(xs)
        jr, jf = np.asarray(jr), np.asarray(jf)
        assert np.all(np.isfinite(jr)) and np.all(np.isfinite(jf))
        for k in range(2):
            fd = _central_fd(lambda a: fk(a, spec), xs[k])
            np.testing.assert_allclose(jr[k], fd, atol=1e-7)
            np.testing.assert_allclose(jf[k], fd, atol=1e-7)
        # not trivially zero: at straight, x_ee = (L / 2 + (M - 1) L) a_1 to first order in
        # link 1's bending a_1 = (l2 + l3 - 2 l1) / (3 r)
        expected = (spec.length / 2 + spec.length) * (-2 / (3 * spec.radius))
        assert jr[0, -1, 0, 3, 0, 0] == pytest.approx(expected, rel=1e-9)
        # second derivatives are finite too (smooth in the bending vector) and match FD of the gradient
        z_ee = lambda a: forward_kinematics(a, SPEC1)[..., -1, 2, 3]
        x1 = jnp.asarray(SPEC1.straight_state())
        hz = np.asarray(jax.jit(jax.hessian(z_ee))(x1))
        assert np.all(np.isfinite(hz))
        fdh = _central_fd(jax.jit(jax.vmap(jax.grad(z_ee))), x1, h=1e-5)
        np.testing.assert_allclose(hz, fdh, atol=1e-6)
        assert np.abs(hz).max() > 0.1  # z_ee = L (1 - theta^2 / 6 + ...): curvature at straight


def test_fk_gradients_float32_straight_finite():
    g = jax.jit(jax.grad(lambda a: jnp.sum(forward_kinematics(a, SPEC4)[..., :3, :])))
    assert np.all(np.isfinite(np.asarray(g(SPEC4.straight_state()))))
    assert np.all(np.isfinite(np.asarray(g(SPEC4.straight_state() + 1e-7))))
    assert np.any(np.asarray(g(SPEC4.straight_state())) != 0)


def test_link_transform_gradients_at_theta_zero():
    with jax.enable_x64(True):
        phis = jnp.asarray([0.0, 1.0, -np.pi])
        zeros = jnp.zeros(3)
        tf = lambda t, p: link_transform(t, p, SPEC1)
        # d/dtheta (forward mode) and d/dphi (reverse mode) in one compiled function
        g, gp = jax.jit(jax.vmap(lambda t, p: (jax.jacfwd(tf)(t, p), jax.jacrev(tf, argnums=1)(t, p))))(zeros, phis)
        g, gp = np.asarray(g), np.asarray(gp)
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(gp))
    for k, phi in enumerate(np.asarray(phis)):
        # one-sided FD (theta >= 0) of the numpy reference
        h = 1e-7
        fd = (link_transform_numpy(h, phi, 2.0) - link_transform_numpy(0.0, phi, 2.0)) / h
        np.testing.assert_allclose(g[k], fd, atol=1e-6)
        assert g[k, 0, 3] == pytest.approx(SPEC1.length / 2 * np.cos(phi), abs=1e-9)  # x ~ L theta cos(phi) / 2
    np.testing.assert_allclose(gp, 0.0, atol=1e-12)  # phi is irrelevant when straight


def test_config_gradients_at_straight_are_finite():
    arc = SPEC4.straight_state()

    def grads(a):  # reverse-mode gradient and forward-mode Jacobian of theta and of phi, one compile
        out = []
        for k in (0, 1):
            f = lambda a: arc_lengths_to_config(a, SPEC4)[k]
            out += [jax.grad(lambda a: jnp.sum(f(a)))(a), jax.jacfwd(f)(a)]
        return out

    for g in jax.jit(grads)(arc):
        assert np.all(np.isfinite(np.asarray(g)))
    # theta^2 is smooth in the arc lengths: its gradient matches FD (and is zero at straight)
    with jax.enable_x64(True):
        f = jax.jit(lambda a: jnp.sum(arc_lengths_to_config(a, SPEC1)[0] ** 2, axis=-1))
        grad = jax.jit(jax.grad(f))
        x = jnp.asarray([[1.95, 2.05, 2.0]])
        np.testing.assert_allclose(np.asarray(grad(x)), _central_fd(f, x), atol=1e-6)
        np.testing.assert_allclose(np.asarray(grad(SPEC1.straight_state())), 0.0, atol=1e-12)
    # config_to_arc_lengths gradient at theta = 0
    g = jax.jit(jax.grad(lambda t, p: jnp.sum(config_to_arc_lengths(t, p, SPEC1) ** 2), argnums=(0, 1)))(0.0, 0.3)
    assert all(np.isfinite(float(x)) for x in g)


# ----------------------------------------------------------------------------
# project_state and the frame transforms


def test_project_state_is_the_nearest_valid_state_by_brute_force():
    spec = RobotSpec(1)
    # every valid link state on a 2 mm grid of (l1, l2), l3 = 3L - l1 - l2
    g = np.arange(spec.l_min, spec.l_max + 1e-9, 0.002)
    l1, l2 = np.meshgrid(g, g, indexing="ij")
    grid = np.stack([l1.ravel(), l2.ravel(), 3 * spec.length - l1.ravel() - l2.ravel()], axis=-1)
    grid = grid[(grid[:, 2] >= spec.l_min) & (grid[:, 2] <= spec.l_max)]
    rng = np.random.default_rng(0)
    x = spec.length + rng.normal(size=(40, 3)) * np.array([[0.05], [0.3], [1.0], [3.0]]).repeat(10, 0)
    y = np.asarray(jax.jit(lambda a: project_state(a, spec))(jnp.asarray(x)))
    for xi, yi in zip(x, y):
        assert state_violation(yi[None], spec) is None
        brute = np.min(np.linalg.norm(grid - xi, axis=1))
        # nothing on the grid is nearer than the projection (up to the grid's resolution)
        assert np.linalg.norm(yi - xi) <= brute + 1e-5
        assert np.linalg.norm(yi - xi) >= brute - 0.002
    valid = np.asarray(sample_arc_lengths(jax.random.PRNGKey(2), spec, (20,)))
    np.testing.assert_allclose(np.asarray(project_state(jnp.asarray(valid), spec)), valid, atol=1e-6)


def test_frame_transforms_invert_each_other_and_match_the_matrix_product():
    frames = np.asarray(forward_kinematics(sample_arc_lengths(jax.random.PRNGKey(4), SPEC4, (SPEC4.n_links,)), SPEC4))
    pts = np.random.default_rng(1).normal(size=(7, 3))
    local = np.asarray(points_in_link_frames(jnp.asarray(pts), jnp.asarray(frames)))  # (M, P, 3)
    homog = np.concatenate([pts, np.ones((7, 1))], axis=1)
    expect = np.einsum("mij,pj->mpi", np.linalg.inv(frames[:-1]), homog)[..., :3]
    np.testing.assert_allclose(local, expect, atol=1e-5)
    back = np.asarray(points_from_link_frames(jnp.asarray(local), jnp.asarray(frames)))
    np.testing.assert_allclose(back, np.broadcast_to(pts, back.shape), atol=1e-5)
    one = np.asarray(world_to_frame(jnp.asarray(frames[2]), jnp.asarray(pts)))
    np.testing.assert_allclose(frame_to_world(jnp.asarray(frames[2]), jnp.asarray(one)), pts, atol=1e-5)
