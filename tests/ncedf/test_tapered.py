"""A tapered robot: every link its own radius, in the kinematics, the geometry, the model and the judge.

Truths: the product of the links' own transforms (each link alone is a one-link robot of its
radius), the closed-form distance of a straight link (radial distance minus the link's radius),
dense surface samples against the boxes' closed-form signed distance, and each link's network
used alone.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from ncedf.geometry import robot_link_signed_distances, robot_surface_points
from ncedf.model import ModelConfig, init_params, load_model, save_model, stack_links
from ncedf.robot import RobotSpec, arc_lengths_to_config, forward_kinematics, link_transform, sample_arc_lengths
from ncedf.shapes import make_shape
from scenarios.truth import true_distances_certified
from scenarios.world import Box, MeshObstacle, World

TAPERED = RobotSpec(3, radius=(0.25, 0.2, 0.15))
SMALL = RobotSpec(2, 0.2, (0.03, 0.012), 0.16, 0.24)  # thick base link, thin tip link


def test_equal_radii_collapse_and_a_wrong_count_is_named():
    assert RobotSpec(3, radius=(0.2, 0.2, 0.2)) == RobotSpec(3) and not RobotSpec(3).tapered
    assert TAPERED.tapered and TAPERED.radii == (0.25, 0.2, 0.15) and TAPERED.link(2) == RobotSpec(1, radius=0.15)
    with pytest.raises(ValueError, match="2 link radii given for a robot of 3 links"):
        RobotSpec(3, radius=(0.2, 0.1))
    with pytest.raises(ValueError, match="radius must be > 0"):
        RobotSpec(2, radius=(0.2, -0.1))
    with pytest.raises(ValueError, match="radius must be a finite number"):
        RobotSpec(2, radius=(0.2, float("nan")))
    assert TAPERED.scaled(0.5).scaled(2.0) == TAPERED and TAPERED.scaled(0.5).radii == (0.125, 0.1, 0.075)


def test_the_kinematics_is_the_product_of_each_links_own_transform():
    arcs = sample_arc_lengths(jax.random.PRNGKey(0), TAPERED, (6, 3))
    frames = forward_kinematics(arcs, TAPERED)
    for b in range(6):
        product = np.eye(4)
        for i in range(3):
            link = TAPERED.link(i)
            theta, phi = arc_lengths_to_config(arcs[b, i], link)
            product = product @ np.asarray(link_transform(theta, phi, link), np.float64)
            np.testing.assert_allclose(frames[b, i + 1], product, atol=2e-5)
    # the same chamber strokes bend the thinner link more (theta = stroke / r)
    stroke = jnp.asarray([[1.9, 2.05, 2.05]] * 3)
    theta, _ = arc_lengths_to_config(stroke, TAPERED)
    np.testing.assert_allclose(theta * jnp.asarray(TAPERED.radii), theta[0] * 0.25, rtol=1e-5)


def test_the_exact_distance_of_a_straight_link_is_the_radial_distance_less_its_own_radius():
    rho = np.array([0.5, 0.9, 1.3])
    points = jnp.asarray([[r, 0.0, 2.0 * i + 1.0] for i, r in enumerate(rho)], jnp.float32)  # beside each middle
    d = robot_link_signed_distances(points, TAPERED.straight_state(), TAPERED)
    np.testing.assert_allclose(np.diag(np.asarray(d)), rho - np.array(TAPERED.radii), atol=1e-5)


def test_the_sphere_cover_of_each_link_holds_its_surface():
    arcs = sample_arc_lengths(jax.random.PRNGKey(1), TAPERED, (4, 3))
    coords = jax.random.uniform(jax.random.PRNGKey(2), (3, 500, 3)) * jnp.array([1.0, 2 * np.pi, 1.0])
    coords = coords.at[..., 2].set(1.0)  # lateral surface
    spheres, exact = make_shape("spheres", TAPERED), make_shape("exact", TAPERED)
    for arc in arcs:
        surface = robot_surface_points(coords, arc, TAPERED)  # (3, 500, 3)
        geom = spheres.prepare(arc)
        for i in range(3):
            gap = np.linalg.norm(surface[i][:, None] - geom.centres[i][None], axis=-1).min(axis=1) - geom.radius[i]
            assert gap.max() <= 1e-5
        probe = jax.random.uniform(jax.random.PRNGKey(3), (300, 3), minval=-3.0, maxval=6.0)
        assert np.all(np.asarray(spheres.distances(probe, arc)) <= np.asarray(exact.distances(probe, arc)) + 1e-5)


def test_a_tapered_model_round_trips_and_each_link_uses_its_own_network(tmp_path):
    config = ModelConfig(2, 8)
    params = stack_links([init_params(jax.random.PRNGKey(k), config) for k in range(3)])
    save_model(tmp_path / "tapered", params, config, TAPERED, {})
    model = load_model(tmp_path / "tapered")
    assert model.spec == TAPERED and dict(model.metadata["robot"])["radius"] == (0.25, 0.2, 0.15)
    links = model.links()
    assert [m.spec for m in links] == [TAPERED.link(i) for i in range(3)]
    arc = sample_arc_lengths(jax.random.PRNGKey(4), TAPERED, (3,))
    points = jax.random.uniform(jax.random.PRNGKey(5), (40, 3), minval=-2.0, maxval=4.0)
    whole = model.robot_link_distances(points, arc)
    frames = forward_kinematics(arc, TAPERED)
    shape = make_shape("ncedf", TAPERED, model=model)
    pairs = jnp.asarray(np.repeat(np.arange(3), 40))
    paired = shape.pair_distances(shape.prepare(arc), jnp.tile(points, (3, 1)), pairs).reshape(3, 40)
    for i, one in enumerate(links):
        local = (points - frames[i, :3, 3]) @ frames[i, :3, :3]
        theta, phi = arc_lengths_to_config(arc[i], one.spec)
        alone = one.link_distance(local, theta, phi)
        np.testing.assert_allclose(whole[i], alone, atol=1e-5)
        np.testing.assert_allclose(paired[i], alone, atol=1e-5)
    assert not np.allclose(whole[0], whole[1], atol=1e-3)  # the networks differ
    with pytest.raises(ValueError, match="radius"):
        make_shape("ncedf", RobotSpec(3), model=model)


def _dense_surface(arc, spec: RobotSpec, spacing: float) -> np.ndarray:
    """Every link's lateral surface and the end disks at most ``spacing`` apart, world, (N, 3)."""
    u = np.linspace(0.0, 1.0, int(np.ceil(1.3 * spec.length / spacing)) + 1)
    psi = np.linspace(0.0, 2 * np.pi, int(np.ceil(2 * np.pi * spec.thickest / spacing)), endpoint=False)
    w = np.linspace(0.0, 1.0, int(spec.thickest / spacing) + 1)
    lateral = np.stack(np.broadcast_arrays(u[:, None], psi[None], 1.0), -1).reshape(-1, 3)
    disks = np.concatenate([np.stack(np.broadcast_arrays(end, psi[None], w[:, None]), -1).reshape(-1, 3)
                            for end in (0.0, 1.0)])
    coords = np.concatenate([lateral, disks])
    points = robot_surface_points(jnp.asarray(np.broadcast_to(coords, (spec.n_links,) + coords.shape)), arc, spec)
    return np.asarray(points, np.float64).reshape(-1, 3)


def _box_sdf(points: np.ndarray, centre, half) -> np.ndarray:
    q = np.abs(points - np.asarray(centre)) - np.asarray(half)
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


@pytest.mark.parametrize("gap", [0.004, -0.004])
def test_the_judge_sees_each_links_own_radius(gap):
    """A box beside the thick base link and one beside the thin tip link, 4 mm clear or 4 mm in: the
    judged distance (box and mesh judges) within 1 mm of dense surface samples, or a collision (a
    link judged with the other's radius would be 18 mm off)."""
    arc = np.array([[0.2, 0.2, 0.2], [0.19, 0.205, 0.205]])
    surface = _dense_surface(jnp.asarray(arc, jnp.float32), SMALL, 0.0015)
    for link, z in ((0, 0.1), (1, 0.25)):  # beside the link's lower half, towards +x (link 2 bends there)
        half = np.array([0.05, 0.05, 0.02])
        centre = np.array([0.3, 0.0, z])
        for _ in range(8):  # slide the box along -x until its closed-form gap to the samples is ``gap``
            centre[0] -= _box_sdf(surface, centre, half).min() - gap
        world = World(boxes=(Box(tuple(centre), tuple(2 * half)),))
        low = _box_sdf(surface, centre, half).min()
        box = trimesh_box(centre, half)
        for judged_world in (world, World(meshes=(MeshObstacle(box.vertices, box.faces),))):
            values, _ = true_distances_certified(judged_world, SMALL, arc[None], np.zeros(1))
            if gap > 0:  # never below the truth, within its 1 mm certificate of it
                assert low - 0.0016 <= values[0, 0] <= low + 0.0011, (link, values[0, 0], low)
            else:
                assert values[0, 0] < 0, (link, values[0, 0], low)


def trimesh_box(centre, half):
    return trimesh.creation.box(extents=2 * np.asarray(half)).apply_translation(centre)


def test_evaluate_reports_every_link_of_a_tapered_model(tmp_path, capsys):
    from ncedf.evaluate import main

    config = ModelConfig(2, 8)
    params = stack_links([init_params(jax.random.PRNGKey(k), config) for k in range(3)])
    save_model(tmp_path / "tapered", params, config, TAPERED, {})
    assert main(["--model", str(tmp_path / "tapered"), "--configs", "2", "--points", "64"]) == 0
    out = capsys.readouterr().out
    assert [line.split(";")[0] for line in out.splitlines() if line.startswith("link:")] == [
        f"link: L = 2 m, r = {r:g} m" for r in TAPERED.radii]
    assert "one 3-link configuration" in out


def test_a_runner_given_a_tapered_model_for_other_links_says_which(tmp_path):
    from scenarios.episode import EpisodeSettings, robot_spec

    config = ModelConfig(2, 8)
    save_model(tmp_path / "tapered", stack_links([init_params(jax.random.PRNGKey(k), config) for k in range(3)]),
               config, TAPERED, {})
    settings = EpisodeSettings(scenario="cluttered", links=3, seed=0, model=str(tmp_path / "tapered"))
    assert robot_spec(settings) == TAPERED
    with pytest.raises(ValueError, match="a tapered robot of 3 links, not 4: run it with --links 3"):
        robot_spec(EpisodeSettings(scenario="cluttered", links=4, seed=0, model=str(tmp_path / "tapered")))
