"""Evaluate a trained N-CEDF against exact distances, computed on the spot.

    python -m ncedf.evaluate [--model PATH]

Prints the validation metrics (paper's MAE / RMSE / MOE plus the
over-estimation tail, the near field and the surface) on random
configurations and uniformly random points in the training box, and the
inference time of the whole-robot distance for one 4-link configuration
against 500 points.
"""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

from ncedf.compile_cache import add_cache_option, enable_compile_cache
from ncedf.data import ValidationConfig, load_dataset
from ncedf.metrics import NEAR_FIELD
from ncedf.model import ModelError, load_model
from ncedf.robot import RobotSpec, sample_arc_lengths
from ncedf.train import evaluate_model
from ncedf.units import unit

ROWS = (
    ("overall", ("mae", "rmse", "moe", "over_p999", "max_error")),
    ("near field", ("near_mae", "near_rmse", "near_moe", "near_over_p999", "near_max_error")),
)


def inference_times_ms(model, points, arc, repeats: int) -> list[float]:
    """Wall times (ms) of ``repeats`` calls of the jitted whole-robot distance of one configuration
    ``arc`` (M, 3) to ``points`` (P, 3), after one call that compiles."""
    fn = jax.jit(model.robot_distance)
    fn(points, arc).block_until_ready()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn(points, arc).block_until_ready()
        times.append(1e3 * (time.perf_counter() - start))
    return times


def timed_links(model) -> int:
    """The links of the timed configuration: 4 (the paper's), or a tapered model's own."""
    return model.spec.n_links if model.spec.tapered else 4


#: Obstacle points of the inference timing (about the cluttered scene's observed cloud).
INFERENCE_POINTS = 500


def inference_ms(model, links: int, points: int = INFERENCE_POINTS, repeats: int = 200, seed: int = 0) -> float:
    """Median wall time (ms) of ``robot_distance`` for one ``links``-link configuration."""
    spec = RobotSpec(links, **model.spec.link_geometry())
    k_arc, k_pts = jax.random.split(jax.random.PRNGKey(seed))
    arc = sample_arc_lengths(k_arc, spec, (spec.n_links,))
    pts = unit(spec) * jax.random.uniform(k_pts, (points, 3), minval=-4.0, maxval=8.0)
    return float(np.median(inference_times_ms(model, pts, arc, repeats)))


def report_link(model, val_cfg: ValidationConfig, args) -> None:
    """Print one link network's error table against exact distances."""
    val = load_dataset(val_cfg, model.spec)
    metrics = evaluate_model(model, val)
    length = model.spec.length
    print(f"link: L = {length:g} m, r = {model.spec.radius:g} m; validation: {args.configs} configurations x "
          f"{args.points} points (seed {args.seed}), exact labels; near field = true distance < "
          f"{NEAR_FIELD * unit(model.spec):g} m ({100 * metrics['near_fraction']:.1f}% of points)")
    scale, label = (1e3, "mm") if length < 1.0 else (1.0, "m")  # four decimals of a small link's errors
    print(f"{'':12s} {'MAE':>8s} {'RMSE':>8s} {'MOE':>8s} {'over p99.9':>11s} {'max err':>8s}   ({label})")
    for name, keys in ROWS:
        print(f"{name:12s} " + " ".join(f"{scale * metrics[k]:{11 if 'p999' in k else 8}.4f}" for k in keys))
    print(f"per link length: MAE / L = {metrics['mae'] / length:.5f}, MOE / L = {metrics['moe'] / length:.5f}")
    print(f"surface points: mean prediction {scale * metrics['surface_mean']:+.4f} {label}, "
          f"MAE {scale * metrics['surface_mae']:.4f} {label}")


def main(argv=None) -> int:
    from recorder.cli import OneLineParser, path_text, positive

    p = OneLineParser(prog="python -m ncedf.evaluate", description=__doc__.split("\n\n")[0])
    val = ValidationConfig()
    p.add_argument("--model", default=None, type=path_text, help="weights file or stem (default: the shipped model)")
    p.add_argument("--configs", type=positive, default=val.n_configs,
                   help=f"validation configurations (default {val.n_configs})")
    p.add_argument("--points", type=positive, default=val.n_points,
                   help=f"random points per configuration (default {val.n_points})")
    p.add_argument("--seed", type=int, default=val.seed, help="validation seed")
    add_cache_option(p)
    args = p.parse_args(argv)
    enable_compile_cache(not args.no_cache)
    try:
        model = load_model(args.model)
        val_cfg = ValidationConfig(n_configs=args.configs, n_points=args.points, seed=args.seed,
                                   box_min=model.domain[0], box_max=model.domain[1])
    except (ModelError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from recorder.cli import EXIT_STATUS, Stopped, stop_on_signals

    try:
        with stop_on_signals():
            cfg = model.config
            print(f"model: {args.model or 'shipped default'}  {cfg.layers} layers x {cfg.width}, "
                  f"encoding {cfg.encoding}, output {cfg.output}")
            for link in model.links():
                report_link(link, val_cfg, args)
            links = timed_links(model)
            print(f"inference: {inference_ms(model, links):.3f} ms for one {links}-link configuration against "
                  f"{INFERENCE_POINTS} points (median, {jax.devices()[0].platform})")
    except Stopped as stop:
        print(f"stopped by {stop}: nothing written", file=sys.stderr)
        return EXIT_STATUS[stop.signum]
    return 0


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
