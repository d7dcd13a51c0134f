"""Tests of ncedf.geometry against independent truths.

References built here from scratch in numpy: a dense parametric grid of the
link surface (tube + end disks) queried with a KD-tree (brute force), the
capped-cylinder closed form, trimesh containment, the analytic area split of a
torus wedge, Pappus' volume, and a hand-made world -> link transform chain.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

from ncedf.geometry import link_signed_distance, robot_mesh, robot_signed_distance, sample_link_surface
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths

SPEC1 = RobotSpec(1)
L, R = SPEC1.length, SPEC1.radius

# jitted entry points (spec static) to keep compile and dispatch time low
link_sd = jax.jit(link_signed_distance, static_argnums=3)
robot_sd = jax.jit(robot_signed_distance, static_argnums=2)
fk = jax.jit(forward_kinematics, static_argnums=1)
sample_arcs = jax.jit(sample_arc_lengths, static_argnums=(1, 2))
sample_surface = jax.jit(sample_link_surface, static_argnums=(1, 4))

PAD = 4096


def link_distance(points, theta, phi, dtype=jnp.float32):
    """``link_sd`` for SPEC1 on (P, 3) points, as float64 numpy.

    The points are zero-padded to a multiple of PAD rows (each point's distance
    is computed independently), so all tests share one compiled shape per dtype.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    padded = np.zeros((-(-n // PAD) * PAD, 3))
    padded[:n] = points
    sd = link_sd(jnp.asarray(padded, dtype), float(theta), float(phi), SPEC1)
    return np.asarray(sd, dtype=np.float64)[:n]


def surface_tree(points):
    """KD-tree for exact nearest-surface-point queries.

    ``compact_nodes=False, balanced_tree=False`` only change the tree's layout
    (queries stay exact); on these dense surfaces they make queries from points
    inside the tube or far away several times faster.
    """
    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def config_of(arc):
    """Paper eq. (1) in numpy."""
    l1, l2, l3 = arc[..., 0], arc[..., 1], arc[..., 2]
    theta = 2.0 * np.sqrt(l1**2 + l2**2 + l3**2 - l1 * l2 - l1 * l3 - l2 * l3) / (3.0 * R)
    return theta, np.arctan2(np.sqrt(3.0) * (l2 - l3), l2 + l3 - 2.0 * l1)


# ----------------------------------------------------------------------------
# brute-force surface (numpy, from scratch)


def backbone_frames(theta, phi, s):
    """Backbone point c(s), tangent t(s), unit normal towards the centre of curvature n_in and binormal."""
    u = np.array([np.cos(phi), np.sin(phi), 0.0])  # bending direction
    b = np.array([-np.sin(phi), np.cos(phi), 0.0])
    ez = np.array([0.0, 0.0, 1.0])
    if theta == 0.0:
        c = s[:, None] * ez
        t = np.broadcast_to(ez, c.shape)
        n = np.broadcast_to(u, c.shape)
    else:
        k = theta / L
        a = k * s
        c = ((1 - np.cos(a)) / k)[:, None] * u + (np.sin(a) / k)[:, None] * ez
        t = np.sin(a)[:, None] * u + np.cos(a)[:, None] * ez
        n = np.cos(a)[:, None] * u - np.sin(a)[:, None] * ez  # towards the centre (rho u)
    return c, t, n, np.broadcast_to(b, c.shape)


def dense_surface(theta, phi, h=0.002, parts=False):
    """Dense grid on the link surface, spacing about h (lateral and disks)."""
    n_s = int(np.ceil(L / h)) + 1
    n_a = int(np.ceil(2 * np.pi * R * (1 + theta / L * R) / h))
    s = np.linspace(0.0, L, n_s)
    ang = np.linspace(0.0, 2 * np.pi, n_a, endpoint=False)
    c, _, n, b = backbone_frames(theta, phi, s)
    lat = c[:, None] + R * (np.cos(ang)[None, :, None] * n[:, None] + np.sin(ang)[None, :, None] * b[:, None])
    lat = lat.reshape(-1, 3)
    rad = np.linspace(0.0, R, int(np.ceil(R / h)) + 1)
    caps = []
    for s_end in (0.0, L):
        ce, _, ne, be = backbone_frames(theta, phi, np.array([s_end]))
        rr, aa = np.meshgrid(rad, ang, indexing="ij")
        disk = ce[0] + (rr * np.cos(aa))[..., None] * ne[0] + (rr * np.sin(aa))[..., None] * be[0]
        caps.append(disk.reshape(-1, 3))
    caps = np.concatenate(caps)
    if parts:
        return lat, caps
    return np.concatenate([lat, caps])


def query_points(theta, phi, rng, n=1500):
    """Points inside, near and outside the link (link frame)."""
    s = rng.uniform(0, L, n)
    c, _, nrm, b = backbone_frames(theta, phi, s)
    ang = rng.uniform(0, 2 * np.pi, n)
    rad = R * rng.uniform(0.0, 2.5, n)
    near = c + rad[:, None] * (np.cos(ang)[:, None] * nrm + np.sin(ang)[:, None] * b)
    box = rng.uniform([-1.5, -1.5, -0.8], [1.5, 1.5, 2.8], (n, 3))
    return np.concatenate([near, box])


CONFIGS = [(0.0, 0.0), (0.4, 1.0), (1.3, -2.5), (2.3, 2.9)]
# Grid spacing of the brute-force surfaces: 2 mm for the configuration that the
# surface-sampling test uses too, 3 mm for the others.
FINE = (1.3, -2.5)


def spacing(theta, phi):
    return 0.002 if (theta, phi) == FINE else 0.003


@functools.lru_cache(maxsize=None)
def brute_tree(theta, phi):
    return surface_tree(dense_surface(theta, phi, h=spacing(theta, phi)))


# ----------------------------------------------------------------------------
# closed form vs brute force


@pytest.mark.parametrize("theta, phi", CONFIGS)
def test_link_distance_matches_dense_brute_force(theta, phi):
    rng = np.random.default_rng(int(theta * 100) + 7)
    pts = query_points(theta, phi, rng)
    sd = link_distance(pts, theta, phi)
    bf, _ = brute_tree(theta, phi).query(pts)
    # grid points lie on the surface: brute force >= true distance >= brute force - resolution.
    # The resolution bound is the grid spacing h (2e-3 at h = 2 mm, 3e-3 at 3 mm): every
    # surface point is within sqrt(h_s^2 + h_a^2) / 2 <= 0.74 h of a grid point.
    h = spacing(theta, phi)
    assert np.all(bf >= np.abs(sd) - 2e-5)
    assert np.all(bf - np.abs(sd) <= h)
    assert np.mean(sd < 0) > 0.1 and np.mean(sd > 0) > 0.5  # both sides exercised


@pytest.mark.parametrize("theta, phi", CONFIGS[2:])
def test_link_sign_matches_trimesh_containment(theta, phi):
    rng = np.random.default_rng(11)
    pts = query_points(theta, phi, rng, n=800)
    arc = np.array([[L - R * theta * np.cos(phi + 2 * np.pi * j / 3) for j in range(3)]])
    mesh = robot_mesh(arc, SPEC1, rings=64, around=64)
    assert mesh.is_watertight
    sd = link_distance(pts, theta, phi)
    # chord error of the mesh is < 0.5 mm; keep points 3 mm away from the surface
    far = np.abs(sd) > 3e-3
    inside = mesh.contains(pts[far])
    np.testing.assert_array_equal(inside, sd[far] < 0)


def capped_cylinder_sd(p):
    rxy = np.hypot(p[:, 0], p[:, 1])
    z = p[:, 2]
    inside = (rxy <= R) & (z >= 0) & (z <= L)
    d_in = -np.minimum(np.minimum(R - rxy, z), L - z)
    d_out = np.hypot(np.maximum(rxy - R, 0.0), np.maximum(np.maximum(-z, z - L), 0.0))
    return np.where(inside, d_in, d_out)


def test_straight_link_is_capped_cylinder():
    rng = np.random.default_rng(12)
    pts = np.concatenate([rng.uniform([-0.5, -0.5, -0.5], [0.5, 0.5, 2.5], (3000, 3)),
                          query_points(0.0, 0.0, rng, 500)])
    ref = capped_cylinder_sd(pts)
    for phi in (0.0, 1.3, -3.0):
        sd = link_distance(pts, 0.0, phi)
        np.testing.assert_allclose(sd, ref, atol=2e-6)


def test_small_theta_continuity_float32():
    rng = np.random.default_rng(13)
    pts = np.concatenate([query_points(0.0, 0.0, rng, 600), rng.uniform([-3, -3, -2], [3, 3, 5], (300, 3))])
    base = capped_cylinder_sd(pts)
    for theta in (1e-7, 1e-5, 1e-4, 1e-3, 0.0099999, 0.01, 0.0100001, 0.02):
        sd = link_distance(pts, theta, 0.7)
        with jax.enable_x64(True):
            sd64 = link_distance(pts, theta, 0.7, jnp.float64)
        np.testing.assert_allclose(sd, sd64, atol=5e-6)  # no float32 blow-up
        # the body moves by at most (L / 2 + r) theta (+ O(theta^2)) as theta leaves 0
        assert np.max(np.abs(sd64 - base)) <= (L / 2 + R) * theta * 1.01 + 1e-12
    # neighbours across the series switch
    a = link_distance(pts, 0.0099999, 0.7)
    b = link_distance(pts, 0.0100001, 0.7)
    np.testing.assert_allclose(a, b, atol=2e-6)


# ----------------------------------------------------------------------------
# gradients


def test_eikonal_and_gradient_direction():
    rng = np.random.default_rng(14)
    grad = jax.jit(jax.vmap(jax.grad(link_signed_distance), in_axes=(0, None, None, None)), static_argnums=3)
    for theta, phi in CONFIGS[2:]:
        lat, caps = dense_surface(theta, phi, h=0.003, parts=True)
        pts = query_points(theta, phi, rng, n=1200)
        sd = link_distance(pts, theta, phi)
        d_lat, i_lat = surface_tree(lat).query(pts)
        d_cap, i_cap = surface_tree(caps).query(pts)
        c, *_ = backbone_frames(theta, phi, np.linspace(0, L, 4001))
        d_axis, _ = cKDTree(c).query(pts)
        keep = (np.abs(sd) > 0.01) & (np.abs(sd) < 0.5) & (d_axis > 0.02)
        keep &= ~((sd < 0) & (np.abs(d_lat - d_cap) < 0.01))  # interior medial surface lateral/cap
        assert keep.sum() > 300
        # gradient at all points (one compiled shape for both configurations), checked where kept
        g = np.asarray(grad(jnp.asarray(pts, jnp.float32), theta, phi, SPEC1), dtype=np.float64)[keep]
        np.testing.assert_allclose(np.linalg.norm(g, axis=-1), 1.0, atol=1e-3)
        # direction: from the nearest surface point (brute force: the nearer of the nearest
        # lateral and the nearest disk grid point) towards the point, times the sign
        lat_nearer = (d_lat <= d_cap)[keep]
        d = np.where(lat_nearer, d_lat[keep], d_cap[keep])
        q = np.where(lat_nearer[:, None], lat[i_lat[keep]], caps[i_cap[keep]])
        ok = d > 0.05
        ref = (pts[keep][ok] - q[ok]) / d[ok, None] * np.sign(sd[keep][ok])[:, None]
        cosang = np.sum(ref * g[ok], axis=-1)
        assert np.all(cosang > 0.995)


def test_gradients_finite_at_straight():
    spec = RobotSpec(2)
    rng = np.random.default_rng(15)
    pts = jnp.asarray(rng.uniform([-1, -1, -0.5], [1, 1, 4.5], (64, 3)), jnp.float32)
    arc = spec.straight_state()
    f = lambda p, a: jnp.sum(robot_signed_distance(p, a, spec))
    # the distance and its gradients in one compiled function
    sd_and_grads = jax.jit(lambda p, a: (robot_signed_distance(p, a, spec), jax.grad(f, argnums=(0, 1))(p, a)))
    sd, (gp, ga) = sd_and_grads(pts, arc)
    assert np.all(np.isfinite(np.asarray(gp))) and np.all(np.isfinite(np.asarray(ga)))
    # |grad_p| = 1 at straight too (points off the axis and off the medial surfaces)
    g = np.asarray(gp)
    sd = np.asarray(sd)
    rxy = np.hypot(np.asarray(pts)[:, 0], np.asarray(pts)[:, 1])
    clear = (np.abs(sd) > 0.01) & (rxy > 0.02) & (sd > 0)
    np.testing.assert_allclose(np.linalg.norm(g[clear], axis=-1), 1.0, atol=1e-4)


def test_distance_gradient_wrt_arc_at_straight_matches_fd():
    """The distance is differentiable in the bending vector at theta = 0; its true gradient is not zero there."""
    with jax.enable_x64(True):
        p = jnp.asarray([[0.25, 0.05, 1.9]])
        f = lambda a: robot_signed_distance(p, a, SPEC1)[0]
        x = np.asarray(SPEC1.straight_state())
        h = 1e-6
        xs = np.concatenate([x + h * np.eye(3)[:, None, :], x - h * np.eye(3)[:, None, :]])
        # the gradient and the function values for central differences in one compiled function
        g, ys = jax.jit(lambda x, xs: (jax.grad(f)(x), jax.vmap(f)(xs)))(jnp.asarray(x), jnp.asarray(xs))
        g, ys = np.asarray(g), np.asarray(ys)
        fd = (ys[:3] - ys[3:]) / (2 * h)
    np.testing.assert_allclose(g.ravel(), fd.ravel(), atol=1e-4)


# ----------------------------------------------------------------------------
# robot distance = min over links in link frames


def test_robot_distance_is_min_over_hand_transformed_links():
    spec = RobotSpec(4)
    arc = np.asarray(sample_arcs(jax.random.key(16), spec, (4,)), dtype=np.float64)
    frames = np.asarray(fk(jnp.asarray(arc), spec), dtype=np.float64)
    theta, phi = config_of(arc)
    rng = np.random.default_rng(17)
    pts = (frames[1:, None, :3, 3] + rng.normal(0, 0.3, (4, 200, 3))).reshape(-1, 3)
    per_link = []
    for i in range(4):
        inv = np.linalg.inv(frames[i])
        local = pts @ inv[:3, :3].T + inv[:3, 3]
        per_link.append(link_distance(local, theta[i], phi[i]))
    ref = np.min(per_link, axis=0)
    sd = np.asarray(robot_sd(jnp.asarray(pts, jnp.float32), jnp.asarray(arc, jnp.float32), spec))
    np.testing.assert_allclose(sd, ref, atol=2e-5)
    # and, outside the robot, it is the brute-force distance to the union of the link surfaces
    clouds = [dense_surface(theta[i], phi[i], h=0.004) @ frames[i][:3, :3].T + frames[i][:3, 3] for i in range(4)]
    bf, _ = surface_tree(np.concatenate(clouds)).query(pts)
    out = sd > 0
    assert np.all(bf[out] >= sd[out] - 2e-5) and np.all(bf[out] - sd[out] <= 4e-3)


# ----------------------------------------------------------------------------
# surface sampling


def test_sampled_points_lie_on_the_surface():
    theta, phi = 1.3, -2.5
    assert (theta, phi) == FINE  # the 2 mm brute-force surface
    pts = np.asarray(sample_surface(jax.random.key(18), 4000, theta, phi, SPEC1), dtype=np.float64)
    assert pts.shape == (4000, 3)
    d, _ = brute_tree(theta, phi).query(pts)
    assert np.all(d < 2e-3)
    np.testing.assert_allclose(link_distance(pts, theta, phi), 0.0, atol=1e-5)


@pytest.mark.parametrize("theta, phi", [(0.0, 0.0), (2.3, 0.8)])
def test_sampling_is_uniform_by_area(theta, phi):
    n = 40000
    pts = np.asarray(sample_surface(jax.random.key(19), n, theta, phi, SPEC1), dtype=np.float64)
    # rotate into the bending plane (bending towards +x) by hand
    c, s = np.cos(phi), np.sin(phi)
    x, y, z = c * pts[:, 0] + s * pts[:, 1], -s * pts[:, 0] + c * pts[:, 1], pts[:, 2]
    on_start = np.abs(z) < 1e-5
    end_n = np.array([np.sin(theta), np.cos(theta)])  # (x, z) of the end tangent
    end_c = np.array([L * (1 - np.cos(theta)) / theta if theta else 0.0, L * np.sin(theta) / theta if theta else L])
    on_end = np.abs((x - end_c[0]) * end_n[0] + (z - end_c[1]) * end_n[1]) < 1e-5
    lateral = ~(on_start | on_end)
    total = 2 * np.pi * R * L + 2 * np.pi * R**2
    p_cap = np.pi * R**2 / total
    tol = 5 * np.sqrt(p_cap * (1 - p_cap) / n)
    assert abs(on_start.mean() - p_cap) < tol and abs(on_end.mean() - p_cap) < tol
    # disks: uniform by area -> P(radius < r') = (r'/R)^2; test the median radius R / sqrt(2)
    r0 = np.hypot(x[on_start], y[on_start])
    assert np.median(r0) == pytest.approx(R / np.sqrt(2), abs=0.01)
    if theta > 0:
        # lateral: outer half (farther from the torus axis than the backbone) vs inner half.
        # Area element r (1 + kappa r cos psi) ds dpsi -> inner / outer = (pi - 2 kappa r) / (pi + 2 kappa r)
        rho = L / theta
        outer = np.hypot(x[lateral] - rho, z[lateral]) > rho
        a = theta / L * R
        p_in = (np.pi - 2 * a) / (2 * np.pi)
        tol = 5 * np.sqrt(p_in * (1 - p_in) / lateral.sum())
        assert abs((~outer).mean() - p_in) < tol
        ratio = (~outer).sum() / outer.sum()
        assert ratio == pytest.approx((1 - 2 * a / np.pi) / (1 + 2 * a / np.pi), abs=0.03)
        # uniform along the arc: the angle around the torus axis is uniform in [0, theta]
        ang = np.arctan2(z[lateral], rho - x[lateral])
        hist, _ = np.histogram(ang, bins=10, range=(0, theta))
        np.testing.assert_allclose(hist / lateral.sum(), 0.1, atol=0.01)
    else:
        hist, _ = np.histogram(z[lateral], bins=10, range=(0, L))
        np.testing.assert_allclose(hist / lateral.sum(), 0.1, atol=0.01)
        ang = np.arctan2(y[lateral], x[lateral])
        hist, _ = np.histogram(ang, bins=8, range=(-np.pi, np.pi))
        np.testing.assert_allclose(hist / lateral.sum(), 1 / 8, atol=0.012)


# ----------------------------------------------------------------------------
# mesh


def test_robot_mesh_closed_tubes_with_pappus_volume():
    spec = RobotSpec(3)
    arc = np.asarray(sample_arcs(jax.random.key(20), spec, (3,)), dtype=np.float64)
    mesh = robot_mesh(arc, spec)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert len(mesh.split(only_watertight=True)) == 3
    v_ref = 3 * np.pi * R**2 * L  # Pappus: cross-section area times backbone length, per link
    assert mesh.volume == pytest.approx(v_ref, rel=0.03)  # 24 x 24 polygonal tube
    fine = robot_mesh(arc, spec, rings=96, around=96)
    assert fine.volume == pytest.approx(v_ref, rel=2e-3)
    assert fine.volume > mesh.volume > 0  # outward orientation, inscribed polygons
    # vertices lie on the exact surface of some link
    frames = np.asarray(fk(jnp.asarray(arc), spec), dtype=np.float64)
    theta, phi = config_of(arc)
    per_link = []
    for i in range(3):
        inv = np.linalg.inv(frames[i])
        local = mesh.vertices @ inv[:3, :3].T + inv[:3, 3]
        per_link.append(np.abs(link_distance(local, theta[i], phi[i])))
    assert np.all(np.min(per_link, axis=0) < 1e-5)
