"""MPPI step time per shape representation: broad phase vs brute force, same run.

    python bench/mppi_step.py --links 4 5 7 --samples 800 --horizon 20 --points 500
    python bench/mppi_step.py --quick
    python bench/mppi_step.py --links 4 7 --reps ncedf --k2 12 --segments 2   # other broad-phase sizes

Scene: the paper's cluttered environment as ``scenarios.cluttered`` defines it
(Sec. VI-D; three boxes, points on their faces, two spheres of 30 surface points)
at t = 0, observed with about ``--points`` points, and its goal. The robot runs
closed loop from the straight state with the broad-phase controller; the brute-force
controller (``broad_phase=None``) is then run on the first ``--ref-steps`` of the
same inputs (state, plan, key), so both see identical samples. Reported per (links, representation):

  median / p95 step time of the broad phase over ``--steps`` steps after
  compilation; its compile time (ahead-of-time ``lower().compile()``); the
  brute-force median over ``--ref-steps`` steps (>= 2; fewer than ``--steps``:
  it takes seconds per step; printed as column n); their ratio;
  agreement: the fraction of the N x H rollout states whose min distance equals
  brute force (``exact``: bit-identical; ``1e-5``: within 1e-5 m), the largest
  difference, and the relative change of the executed control and of the whole
  updated plan, ``||a_bp - a_bf|| / ||a_bf||``.

With more than 6 links the horizon is ``--horizon-long`` (release: 7) unless
``--same-horizon``. Representations: ncedf, spheres, exact, pointcloud:1000 by
default; pointcloud:5000 only when named in ``--reps`` (2 brute-force steps).

``--closed-loop`` (or ``--closed-loop-only``) also runs one short episode twice,
broad phase on and off (same seed; 4 links; an obstacle ball between the tip
and the goal; ``--cl-samples`` rollouts, ``--cl-steps`` steps) and prints the
largest deviation of the arc-length trajectories and each run's minimum exact
distance to the obstacle points.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.broad_phase import BroadPhase
from ncedf.controller import Controller, ControllerConfig
from ncedf.mppi import MPPIConfig, mppi_step
from ncedf.robot import RobotSpec, project_state
from ncedf.shapes import make_shape
from recorder.cli import OneLineParser, exit_with, stoppable
from scenarios import cluttered
from scenarios.observe import make_observer

from arguments import positive


def cluttered_points(n: int, seed: int = 0) -> np.ndarray:
    """About ``n`` observed points of ``scenarios.cluttered``'s world at t = 0: 30 on each
    sphere and the box faces at the density that gives the rest (4 per m^2 gives the paper's ~500)."""
    world = cluttered.make_world()
    box_area = sum(2.0 * (sx * sy + sy * sz + sx * sz) for sx, sy, sz in (b.size for b in world.boxes))
    sphere_count = len(world.spheres) * world.sphere_points
    world = dataclasses.replace(world, density=max(n - sphere_count, 0) / box_area)
    return make_observer(world, seed).observe(0.0)


def build_shape(name, spec, model):
    return make_shape(name, spec, model=model) if name == "ncedf" else make_shape(name, spec)


def timed(fn, *args):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t0


def compiled_step(m, *args):
    """AOT-compile ``ncedf.mppi.mppi_step`` for ``m``'s robot, settings and these argument shapes:
    (callable, compile seconds).

    Compiling without running spares the brute-force path a warm-up step (it
    takes seconds per step); both paths are timed after compilation.
    """
    t0 = time.perf_counter()
    exe = mppi_step.lower(m.spec, m.config, m.shape, *args).compile()
    return (lambda *a: exe(m.shape, *a)), time.perf_counter() - t0


def run(links, rep, args, model, points):
    spec = RobotSpec(links) if model is None else RobotSpec(links, **model.spec.link_geometry())  # the model's robot
    horizon = args.horizon if (links <= 6 or args.same_horizon) else args.horizon_long
    base = dict(samples=args.samples, horizon=horizon, max_points=max(len(points), 1))
    shape = build_shape(rep, spec, model)
    fast = Controller(spec, shape, ControllerConfig(MPPIConfig(**base), broad_phase=BroadPhase(args.k1, args.k2, args.segments)))
    ref = Controller(spec, shape, ControllerConfig(MPPIConfig(**base), broad_phase=None))
    pts, mask = fast.pad_points(points)
    goal = jnp.asarray(cluttered.GOAL, jnp.float32)

    state = fast.init(jax.random.PRNGKey(args.seed)).mppi
    arc = jnp.asarray(spec.straight_state(), jnp.float32)
    step, compile_s = compiled_step(fast, state, arc, goal, pts, mask)
    ref_step, ref_compile = compiled_step(ref, state, arc, goal, pts, mask)
    ref_steps = args.ref_steps_for(rep)
    inputs, outputs, times = [], [], []
    for i in range(args.steps):
        out, dt = timed(step, state, arc, goal, pts, mask)
        if i < ref_steps:
            inputs.append((state, arc))
            outputs.append(out)
        times.append(dt)
        action, state, _ = out
        arc = arc + action * fast.config.mppi.dt
    med = float(np.median(times))
    p95 = float(np.percentile(times, 95))

    ref_times, same_exact, same_tol, max_diff, d_action, d_plan = [], [], [], [], [], []
    for (st, a), (act_f, st_f, info_f) in zip(inputs, outputs):
        (act_r, st_r, info_r), dt = timed(ref_step, st, a, goal, pts, mask)
        ref_times.append(dt)
        df = np.asarray(info_f.rollout_min_distance, np.float64)
        dr = np.asarray(info_r.rollout_min_distance, np.float64)
        diff = np.abs(np.where(np.isfinite(dr), df - dr, 0.0))
        same_exact.append(np.mean(df == dr))
        same_tol.append(np.mean(diff <= 1e-5))
        max_diff.append(diff.max())
        na = np.linalg.norm(np.asarray(act_r))
        d_action.append(np.linalg.norm(np.asarray(act_f) - np.asarray(act_r)) / max(na, 1e-12))
        npl = np.linalg.norm(np.asarray(st_r.nominal))
        d_plan.append(np.linalg.norm(np.asarray(st_f.nominal) - np.asarray(st_r.nominal)) / max(npl, 1e-12))
    ref_med = float(np.median(ref_times))
    return dict(
        links=links, rep=rep, H=horizon, med=med, p95=p95, compile=compile_s,
        ref_med=ref_med, ref_n=len(ref_times), ref_compile=ref_compile, ratio=ref_med / med,
        same_exact=float(np.mean(same_exact)), same_tol=float(np.mean(same_tol)), max_diff=float(np.max(max_diff)),
        d_action=float(np.max(d_action)), d_plan=float(np.max(d_plan)),
    )


def closed_loop(args, model):
    """The same episode with broad_phase=True and False: trajectory deviation and exact clearance.

    4 links from the straight state; the goal is the tip of a random valid state;
    ``--cl-points`` points on a ball of radius 0.4 m halfway between the tip and
    the goal. Both controllers start from the same key, so they draw identical
    samples as long as their states agree.
    """
    from ncedf.geometry import robot_signed_distance
    from ncedf.robot import end_effector_pose, sample_arc_lengths

    spec = RobotSpec(4)
    shape = build_shape("ncedf", spec, model)
    goal_arc = sample_arc_lengths(jax.random.PRNGKey(3), spec, (4,))
    goal = np.asarray(end_effector_pose(goal_arc, spec)[:3, 3], np.float32)
    start = np.asarray(end_effector_pose(spec.straight_state(), spec)[:3, 3])
    rng = np.random.default_rng(args.seed)
    v = rng.normal(size=(args.cl_points, 3))
    cloud = (0.5 * (start + goal) + 0.4 * v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
    exact = jax.jit(lambda a: jnp.min(robot_signed_distance(jnp.asarray(cloud), a, spec)))
    runs = {}
    for bp in (True, False):
        cfg = ControllerConfig(MPPIConfig(samples=args.cl_samples, horizon=args.horizon, max_points=len(cloud)),
                               broad_phase=BroadPhase(args.k1, args.k2, args.segments) if bp else None)
        m = Controller(spec, shape, cfg)
        pts, mask = m.pad_points(cloud)
        st = m.init(jax.random.PRNGKey(args.seed)).mppi
        arc = np.asarray(spec.straight_state(), np.float32)
        traj, clearance, times = [arc.copy()], [], []
        for _ in range(args.cl_steps):
            (action, st, _), dt = timed(mppi_step, spec, cfg, shape, st, jnp.asarray(arc), jnp.asarray(goal), pts, mask)
            times.append(dt)
            arc = np.asarray(project_state(arc + np.asarray(action) * cfg.mppi.dt, spec))  # remove float drift of the sum
            traj.append(arc.copy())
            clearance.append(float(exact(jnp.asarray(arc))))
        tip = np.asarray(end_effector_pose(jnp.asarray(arc), spec)[:3, 3])
        runs[bp] = dict(traj=np.stack(traj), clear=min(clearance), goal=float(np.linalg.norm(tip - goal)),
                        med=float(np.median(times[1:])))
    dev = np.abs(runs[True]["traj"] - runs[False]["traj"]).max(axis=(1, 2))
    print(
        f"closed loop: 4 links, {args.cl_samples} samples, H {args.horizon}, {args.cl_steps} steps, "
        f"{args.cl_points} points on a 0.4 m ball between tip and goal, seed {args.seed}"
    )
    for bp, name in ((True, "broad phase"), (False, "brute force")):
        r = runs[bp]
        print(f"  {name:<12} min exact distance {r['clear']:.4f} m, final goal distance {r['goal']:.3f} m, "
              f"median step {1e3 * r['med']:.0f} ms")
    first = int(np.argmax(dev > 1e-6)) if np.any(dev > 1e-6) else None
    print(f"  max |arc_bp - arc_bf| over the episode {dev.max():.2e} m (first step above 1e-6 m: {first})")
    sys.stdout.flush()


HEADER = (
    f"{'links':>5} {'representation':<16} {'H':>3} {'median ms':>10} {'p95 ms':>8} {'compile s':>9} "
    f"{'brute ms':>9} {'n':>2} {'brute/bp':>9} {'same':>8} {'<=1e-5':>8} {'max |dd| m':>10} "
    f"{'d action':>9} {'d plan':>9}"
)


def fmt(r):
    return (
        f"{r['links']:>5} {r['rep']:<16} {r['H']:>3} {1e3 * r['med']:>10.1f} {1e3 * r['p95']:>8.1f} "
        f"{r['compile']:>9.1f} "
        f"{1e3 * r['ref_med']:>9.0f} {r['ref_n']:>2} {r['ratio']:>9.1f} {100 * r['same_exact']:>7.3f}% "
        f"{100 * r['same_tol']:>7.3f}% {r['max_diff']:>10.2e} {r['d_action']:>9.1e} {r['d_plan']:>9.1e}"
    )


DEFAULT_REPS = "ncedf,spheres,exact,pointcloud:1000"


def main(argv=None):
    p = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--links", type=positive, nargs="+", default=[4, 5, 7])
    p.add_argument("--samples", type=positive, default=800)
    p.add_argument("--horizon", type=positive, default=20)
    p.add_argument("--horizon-long", type=positive, default=7, help="horizon for > 6 links (release)")
    p.add_argument("--same-horizon", action="store_true")
    p.add_argument("--points", type=positive, default=500)
    p.add_argument("--steps", type=positive, default=20, help="timed broad-phase steps after compilation")
    p.add_argument("--ref-steps", type=positive, default=2, help="timed brute-force steps (same inputs), >= 2")
    p.add_argument("--reps", default=DEFAULT_REPS,
                   help="comma-separated representations (default " + DEFAULT_REPS.replace(",", ", ") + ")")
    p.add_argument("--k1", type=positive, default=BroadPhase.k1)
    p.add_argument("--k2", type=positive, default=BroadPhase.k2)
    p.add_argument("--segments", type=positive, default=BroadPhase.capsule_segments, help="capsules per link")
    p.add_argument("--model", default=None, help="N-CEDF weights (default: the shipped model)")
    p.add_argument("--random-model", action="store_true", help="untrained 4x16 network (timing only)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="smoke run: 4 links, 64 samples, H 8, few steps")
    p.add_argument("--closed-loop", action="store_true", help="also run the closed-loop equivalence check")
    p.add_argument("--closed-loop-only", action="store_true", help="only the closed-loop check")
    p.add_argument("--cl-samples", type=positive, default=256)
    p.add_argument("--cl-points", type=positive, default=200)
    p.add_argument("--cl-steps", type=positive, default=60)
    args = p.parse_args(argv)
    if args.quick:
        args.links, args.samples, args.horizon, args.steps, args.ref_steps = [4], 64, 8, 3, 2
        args.reps = "ncedf,spheres,pointcloud:1000,exact"
        args.cl_samples, args.cl_points, args.cl_steps = 64, 40, 10
    args.ref_steps = max(2, min(args.ref_steps, args.steps))
    # pointcloud:5000's brute force takes minutes per step: 2 reference steps at most.
    args.ref_steps_for = lambda rep: (2 if rep.startswith("pointcloud:") and int(rep.split(":")[1]) > 2000
                                      else args.ref_steps)
    reps = [r.strip() for r in args.reps.split(",") if r.strip()]
    if not reps:
        p.error(f"--reps: no representation named in {args.reps!r}")
    for rep in (r for r in reps if r != "ncedf"):  # the network is loaded below
        try:
            make_shape(rep, RobotSpec(4))
        except ValueError as exc:
            p.error(f"--reps: {exc}")

    model = None
    if "ncedf" in reps or args.closed_loop or args.closed_loop_only:
        from ncedf import model as model_mod

        if args.random_model:
            cfg = model_mod.ModelConfig()
            model = model_mod.NCEDF(model_mod.init_params(jax.random.PRNGKey(0), cfg), cfg, RobotSpec(1))
            print("NOTE: untrained random 4x16 network: timings only, agreement not meaningful")
        else:
            try:
                model = model_mod.load_model(args.model)
            except model_mod.ModelError as exc:
                p.error(f"--model: {exc}")
    if args.closed_loop_only:
        closed_loop(args, model)
        return
    points = cluttered_points(args.points, args.seed)
    t_start = time.perf_counter()
    print(
        f"jax {jax.__version__} on {jax.devices()[0].platform}; samples {args.samples}, points {len(points)}, "
        f"k1 {args.k1}, k2 {args.k2}, capsule segments {args.segments}; broad phase timed over "
        f"{args.steps} steps, brute force over the first {args.ref_steps} of them on the same inputs "
        f"(column n; both AOT-compiled first, no warm-up step)"
    )
    if any(r.startswith("pointcloud:") and int(r.split(":")[1]) > 2000 for r in reps):
        print("NOTE: pointcloud with > 2000 points: brute force over 2 steps only (minutes per step)")
    print(HEADER)
    sys.stdout.flush()
    for links in args.links:
        for rep in reps:
            print(fmt(run(links, rep, args, model, points)))
            sys.stdout.flush()
    print(f"total bench time {time.perf_counter() - t_start:.0f} s")
    if args.closed_loop:
        closed_loop(args, model)


if __name__ == "__main__":
    exit_with(stoppable(main))
