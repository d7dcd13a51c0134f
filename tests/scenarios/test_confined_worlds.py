"""The confined-space runners (window, cabinet, pipe, slot, pillars): their worlds, and the exact judge
on a scripted motion through a runner's window (closed form) and into its wall (dense brute force)."""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from ncedf.geometry import robot_surface_points
from ncedf.robot import RobotSpec, config_to_arc_lengths
from recorder import schema
from scenarios import window
from scenarios.episode import EpisodeSettings, build_scene, run_episode
from scenarios.judge import judge_step
from scenarios.solids import OVERLAP, obstacle
from scenarios.world import World

WORLDS = ("window", "cabinet", "pipe", "slot", "pillars")
SPEC = RobotSpec(4)
HEIGHT = 5.0  # m: the window's plane above the base


@pytest.mark.parametrize("name", WORLDS)
def test_each_world_varies_with_its_seed_and_leaves_room_at_the_goal(name):
    module = importlib.import_module(f"scenarios.{name}")
    (first, goal), (second, other) = module.make_world(1), module.make_world(2)
    mesh = first.meshes[0]
    assert mesh.closed and not np.allclose(goal, other)
    assert not np.array_equal(mesh.vertices, second.meshes[0].vertices)
    clearance = np.linalg.norm(mesh.index.distance(goal[None])[0])
    assert clearance >= SPEC.radius + 0.2 and not mesh.index.inside(goal[None])[0]
    scene = build_scene(EpisodeSettings(scenario=name, links=4, seed=0, env_seed=1))
    np.testing.assert_allclose(scene.goal, goal)
    cloud = scene.observer.observe(0.0)
    assert abs(len(cloud) - first.density * mesh.area) <= 1  # the runner's density
    assert np.all(mesh.index.distance(cloud)[0] < 1e-4)  # on the surface


@pytest.mark.parametrize("name", WORLDS)
def test_each_runner_has_help(name, capsys):
    with pytest.raises(SystemExit) as done:
        importlib.import_module(f"scenarios.{name}").main(["--help"])
    assert done.value.code == 0 and "--env-seed" in capsys.readouterr().out


def horizontal_window(offset: float) -> World:
    """The runner's wall laid flat at HEIGHT, its window centred ``offset`` m off the robot's axis."""
    pieces = window.wall_pieces(0.0, 7.0)
    mesh = obstacle(pieces, "flat wall")
    x, y, z = mesh.vertices.T  # (x, y, z) -> (z - 7 + offset, -y, x - x0 + HEIGHT): a rotation and a shift
    flat = np.stack([z - 7.0 + offset, -y, x - window.WALL_X[0] + HEIGHT], axis=1)
    return World(meshes=(obstacle([trimesh.Trimesh(flat, mesh.faces)], "flat wall"),))


def lean(theta: float) -> np.ndarray:
    """The 4-link robot with its first link bent by theta towards +x, the others straight, (4, 3) m."""
    first = np.asarray(config_to_arc_lengths(jnp.asarray(theta), jnp.asarray(0.0), SPEC))
    return np.stack([first] + [np.full(3, SPEC.length)] * 3)


def test_through_the_window_the_judge_gives_the_closed_form_clearance():
    world = horizontal_window(0.0)
    straight = lean(0.0)
    judged = judge_step(world, SPEC, straight, straight, 0.0, 0.05)
    # the straight robot on the window's axis: its side is half the window (less the pieces' growth) minus r away
    assert judged.first_collision_time is None
    assert abs(judged.min_distance - (window.WINDOW / 2 - OVERLAP / 2 - SPEC.radius)) <= judged.certificate + 1e-4


def surface_near_the_wall(arc) -> np.ndarray:
    """Robot surface points every 1 cm or closer, those within 0.5 m of the wall's height."""
    u, psi = np.linspace(0, 1, 241), np.linspace(0, 2 * np.pi, 126, endpoint=False)
    uu, pp = np.meshgrid(u, psi, indexing="ij")
    coords = np.stack([uu.ravel(), pp.ravel(), np.ones(uu.size)], -1)
    points = jax.jit(robot_surface_points, static_argnums=2)(
        jnp.asarray(np.broadcast_to(coords, (SPEC.n_links,) + coords.shape)), jnp.asarray(arc), SPEC)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return points[np.abs(points[:, 2] - HEIGHT) < 0.5]


def test_leaning_into_the_wall_collides_where_brute_force_says():
    world = horizontal_window(0.0)
    mesh = world.meshes[0]
    solid = trimesh.Trimesh(mesh.vertices, mesh.faces)
    thetas = np.linspace(0.0, 0.12, 13)
    first_judged, first_brute = None, None
    for k, (a, b) in enumerate(zip(thetas[:-1], thetas[1:])):
        step = judge_step(world, SPEC, lean(a), lean(b), 0.05 * k, 0.05)
        inside = solid.contains(surface_near_the_wall(lean(b)))  # trimesh's containment, by rays
        if first_judged is None and step.first_collision_time is not None:
            first_judged = k
        if first_brute is None and inside.any():
            first_brute = k
    assert first_judged is not None and first_brute is not None
    assert first_judged <= first_brute <= first_judged + 1


def test_an_episodes_recording_draws_the_worlds_meshes(tmp_path):
    """A runner's recording holds its world's meshes as they are (the viewer draws them beside the
    observed points): one triangle list per mesh at time 0, the mesh's vertices and faces."""
    settings = EpisodeSettings("window", 4, 0, shape="spheres", controller="paper", samples=16, horizon=3,
                               max_steps=1)
    run_episode(settings, tmp_path / "w", formats=("mcap",))
    meshes = build_scene(settings).world.meshes
    factory = DecoderFactory()
    with open(tmp_path / "w.mcap", "rb") as f:
        sent = [(message.log_time, factory.decoder_for(channel.message_encoding, schema_)(message.data))
                for schema_, channel, message in make_reader(f).iter_messages(topics=[schema.OBSTACLE_MESHES])]
    assert len(meshes) >= 1 and [t for t, _ in sent] == [0] * len(meshes)
    for mesh, (_, update) in zip(meshes, sent):
        triangles = update.entities[0].triangles[0]
        np.testing.assert_allclose([[p.x, p.y, p.z] for p in triangles.points], mesh.vertices, atol=1e-6)
        np.testing.assert_array_equal(np.reshape(triangles.indices, (-1, 3)), mesh.faces)
