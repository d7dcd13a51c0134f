"""Shape representations against independent truths (closed-form geometry, dense samples)."""

import functools
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.geometry import robot_signed_distance, robot_surface_points, sample_surface_coords
from ncedf.robot import RobotSpec, sample_arc_lengths
from ncedf.shapes import make_shape

SPEC = RobotSpec(3)


# Everything below runs jitted (one compile per entry point and input shape):
# eager execution would compile every primitive of the geometry separately.


def _arcs(seed, n):
    return sample_arc_lengths(jax.random.PRNGKey(seed), SPEC, (n, SPEC.n_links))


@functools.partial(jax.jit, static_argnames="n")
def _points_near(seed, arc, n=400, spread=0.8):
    """World points around the robot's surface (some inside, most outside)."""
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    coords = jnp.stack([sample_surface_coords(k, n // SPEC.n_links, 0.0, SPEC)
                        for k in jax.random.split(k1, SPEC.n_links)])
    surf = robot_surface_points(coords, arc, SPEC).reshape(-1, 3)
    return surf + spread * jax.random.normal(k2, surf.shape)


@functools.partial(jax.jit, static_argnames="n_per_link")
def _surface_dense(arc, n_per_link, seed=5):
    keys = jax.random.split(jax.random.PRNGKey(seed), SPEC.n_links)
    coords = jnp.stack([sample_surface_coords(k, n_per_link, 0.0, SPEC) for k in keys])
    return robot_surface_points(coords, arc, SPEC).reshape(-1, 3)


_exact = jax.jit(lambda p, a: robot_signed_distance(p, a, SPEC))
_distances = jax.jit(lambda shape, p, a: shape.distances(p, a))


def test_spheres_cover_the_surface_and_never_exceed_exact():
    shape = make_shape("spheres:6", SPEC)
    dist = functools.partial(_distances, shape)
    exact_fn = _exact
    for i, arc in enumerate(_arcs(0, 3)):
        # Every surface point (lateral and end disks) lies in some sphere: distance <= 0.
        surf = _surface_dense(arc, 2000, seed=i)
        assert float(jnp.max(dist(surf, arc))) <= 1e-5
        # Outside the body the spheres never report more than the exact distance.
        pts = _points_near(i, arc)
        exact = exact_fn(pts, arc)
        d = dist(pts, arc)
        outside = exact > 0
        assert int(outside.sum()) > 100
        assert float(jnp.max((d - exact)[outside])) <= 1e-5
        assert float(jnp.max(d[~outside], initial=-1.0)) <= 1e-5


def test_sphere_radius_is_tight_for_a_straight_link():
    # Straight link: the surface point midway between the first two centres is covered exactly
    # at the rim of the spheres, so no smaller radius covers the body.
    n = 5
    spec = RobotSpec(1)
    shape = make_shape(f"spheres:{n}", spec)
    arc = spec.straight_state()
    point = jnp.array([[spec.radius, 0.0, spec.length / n]])
    assert float(robot_signed_distance(point, arc, spec)[0]) == pytest.approx(0.0, abs=1e-6)  # on the surface
    assert float(shape.distances(point, arc)[0]) == pytest.approx(0.0, abs=1e-6)  # on a sphere's rim


def test_pointcloud_converges_to_exact():
    arc = _arcs(1, 1)[0]
    pts = _points_near(3, arc)
    exact = _exact(pts, arc)
    outside = np.asarray(exact > 0.02)
    errors = []
    for n in (30, 300, 3000):
        d = _distances(make_shape(f"pointcloud:{n}", SPEC, seed=1), pts, arc)
        err = np.asarray(d - exact)[outside]
        assert err.min() >= -1e-5  # samples lie on the surface: never nearer than the surface
        errors.append(err.max())
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.06


def test_exact_shape_matches_dense_surface_samples():
    arc = _arcs(2, 1)[0]
    pts = _points_near(4, arc, spread=1.0)
    d = _distances(make_shape("exact", SPEC), pts, arc)
    surf = _surface_dense(arc, 20000)
    brute = jnp.sqrt(jnp.min(jnp.sum((pts[:, None] - surf[None]) ** 2, -1), -1))
    outside = d > 0
    # Dense samples of the surface overestimate by at most about their spacing.
    diff = np.asarray(brute - d)[np.asarray(outside)]
    assert diff.min() >= -1e-4 and diff.max() < 0.03


@pytest.mark.parametrize("name", ["exact", "spheres:4", "pointcloud:300"])
def test_pair_and_batch_forms_agree(name):
    shape = make_shape(name, SPEC)
    arcs = _arcs(3, 2)
    pts = _points_near(5, arcs[0], n=30)
    link = jnp.arange(pts.shape[0]) % SPEC.n_links

    @jax.jit
    def forms(shape, pts, arcs):
        full = jax.vmap(lambda a: shape.link_distances(pts, a))(arcs)  # (B, M, P)
        pair = jax.vmap(lambda a: shape.pair_distances(shape.prepare(a), pts, link))(arcs)
        batched = shape.state_pair_distances(arcs, jax.vmap(lambda a: shape.prepare(a).frames)(arcs),
                                             jnp.broadcast_to(pts, (2,) + pts.shape),
                                             jnp.broadcast_to(link, (2,) + link.shape))
        mins = jax.vmap(shape.min_distance, in_axes=(None, 0))(pts, arcs)
        return full, pair, batched, mins

    full, pair, batched, mins = forms(shape, pts, arcs)
    np.testing.assert_allclose(pair, full[:, link, jnp.arange(pts.shape[0])], atol=1e-5)
    np.testing.assert_allclose(batched, pair, atol=1e-5)
    np.testing.assert_allclose(mins, full.min(axis=(1, 2)), atol=1e-6)


def test_mask_and_empty_cloud():
    shape = make_shape("exact", SPEC)
    arc = SPEC.straight_state()
    pts = jnp.array([[0.0, 0.0, 1.0], [3.0, 0.0, 1.0]])  # the first is inside the robot
    min_distance = jax.jit(shape.min_distance)
    assert float(min_distance(pts, arc, jnp.array([False, True]))) == pytest.approx(2.8, abs=1e-5)
    assert float(min_distance(pts, arc, jnp.array([False, False]))) == np.inf


@pytest.mark.parametrize("name", ["box", "pointcloud", "pointcloud:0", "pointcloud:x", "spheres:-1", "exact:3", 7])
def test_unknown_or_bad_names(name):
    with pytest.raises(ValueError):
        make_shape(name, SPEC)


def test_ncedf_agrees_with_exact_within_model_error():
    from ncedf.model import load_model

    model = load_model()
    shape = make_shape("ncedf", SPEC, model=model)
    arcs = _arcs(7, 3)
    errs = []
    robot_distance = jax.jit(lambda m, p, a: m.robot_distance(p, a))
    for i, arc in enumerate(arcs):
        pts = _points_near(10 + i, arc, spread=0.6)
        exact = jnp.abs(_exact(pts, arc))
        d = _distances(shape, pts, arc)
        errs.append(np.abs(np.asarray(d - exact)))
        # Composition through the chain equals the model's own robot-level function.
        np.testing.assert_allclose(d, robot_distance(model, pts, arc), atol=1e-5)
    err = np.concatenate(errs)
    # The paper's 4 x 16 network: MAE 0.017 m; its errors near the robot stay well under 0.1 m.
    assert err.mean() < 0.017
    assert np.percentile(err, 99) < 0.1
