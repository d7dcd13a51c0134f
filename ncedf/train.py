"""Train a link N-CEDF with optax (paper eq. 7-10).

Loss = distance MSE + lambda_E * Eikonal (gradient w.r.t. the point only)
+ lambda_O * over-estimation ``max(0, pred - d)^2``. Adam (lr 0.003) with
coupled weight decay 1e-5 and the gradient norm clipped to 1.0 before the
update, minibatches of 256; one jitted ``lax.scan`` per epoch. Beyond the
paper, the learning rate decays on a cosine schedule by default
(``--schedule constant`` gives the paper's).

    python -m ncedf.train --layers 4 --width 16 --out runs/ncedf_4x16

The link is the paper's unless ``--length --radius --arc-min --arc-max`` say
otherwise; its training set is drawn in reference units (``ncedf.units``: the
link scaled to 2 m, the box and noise of the paper's recipe) and validated on
exact distances to the link itself. The metadata names the link. ``--radius``
with one value per link (a tapered robot) trains one network per link, each with
the recipe, and saves them as one model of that robot.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm import tqdm

from ncedf.compile_cache import add_cache_option, enable_compile_cache
from ncedf.data import BOX_MAX, BOX_MIN, DatasetConfig, LinkDataset, ValidationConfig, load_dataset
from ncedf.metrics import NEAR_FIELD, distance_metrics
from ncedf.model import (ENCODINGS, MLP, NCEDF, OUTPUTS, ModelConfig, encode, init_params, model_spec, save_model,
                         stack_links)
from ncedf.robot import RobotSpec
from ncedf.train_state import TrainState
from ncedf.units import to_reference, unit
from ncedf.validate import check_fields

SCHEDULES = ("cosine", "constant")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (paper Sec. VI-B, plus the schedule).

    Attributes:
      epochs: passes over the training set.
      batch_size: minibatch size.
      learning_rate: Adam step size (peak of the schedule).
      schedule: "cosine" (decay to 1% over the run) or "constant".
      weight_decay: L2 weight decay added to the gradient (as torch Adam).
      clip_norm: global gradient-norm clip, applied before the update.
      lambda_eikonal: weight of the Eikonal loss.
      lambda_over: weight of the over-estimation loss (0 disables it).
      near_weight: weight of samples nearer than ``NEAR_FIELD`` to the
        surface in the distance and over-estimation terms, relative to 1 for
        the others (1 = the paper's unweighted mean).
      seed: PRNG seed (initialisation and shuffling).
    """

    epochs: int = 100
    batch_size: int = 256
    learning_rate: float = 3e-3
    schedule: str = "cosine"
    weight_decay: float = 1e-5
    clip_norm: float = 1.0
    lambda_eikonal: float = 0.05
    lambda_over: float = 2.0
    near_weight: float = 1.0
    seed: int = 0

    def __post_init__(self):
        check_fields(self, integers=("epochs", "batch_size"), positive=("learning_rate", "near_weight", "clip_norm"),
                     non_negative=("weight_decay", "lambda_eikonal", "lambda_over"), choices={"schedule": SCHEDULES})


def training_arrays(data: LinkDataset, model_cfg: ModelConfig) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Flatten a training set into network inputs (S, D) and raw-output targets (S,).

    The targets are the distance labels, negated inside the link when the
    network learns a signed distance (``output="signed-abs"``).
    """
    encoding, dim = model_cfg.encoding, model_cfg.input_dim
    enc = jax.vmap(encode, in_axes=(0, 0, 0, None))
    x = [enc(jnp.asarray(data.points), data.theta, data.phi, encoding).reshape(-1, dim)]
    signed = model_cfg.output == "signed-abs"
    target = np.where(data.inside, -data.distances, data.distances) if signed else data.distances
    y = [jnp.asarray(target).reshape(-1)]
    if data.surface.shape[1]:
        x.append(enc(jnp.asarray(data.surface), data.theta, data.phi, encoding).reshape(-1, dim))
        y.append(jnp.zeros(data.surface.shape[0] * data.surface.shape[1], jnp.float32))
    return jnp.concatenate(x), jnp.concatenate(y)


def make_optimizer(cfg: TrainConfig, total_steps: int) -> optax.GradientTransformation:
    """Clip, then weight decay, then Adam with the configured schedule."""
    if cfg.schedule == "cosine":
        lr = optax.cosine_decay_schedule(cfg.learning_rate, total_steps, alpha=0.01)
    else:
        lr = cfg.learning_rate
    return optax.chain(
        optax.clip_by_global_norm(cfg.clip_norm),
        optax.add_decayed_weights(cfg.weight_decay),
        optax.scale_by_adam(),
        optax.scale_by_learning_rate(lr),
    )


def loss_terms(params, model_cfg: ModelConfig, x: jnp.ndarray, y: jnp.ndarray, near_weight: float = 1.0) -> dict:
    """Per-batch means of the three loss terms.

    The distance and Eikonal terms act on the raw network output, the
    over-estimation term on the reported distance against ``|y|``.

    Args:
      x: (B, D) encoded inputs whose last three columns are the point.
      y: (B,) targets of the raw output (``training_arrays``), m.
    """
    net = MLP(model_cfg.layers, model_cfg.width)

    def scalar(xi):
        return net.apply(params, xi)

    pred, grads = jax.vmap(jax.value_and_grad(scalar))(x)
    grad_norm = jnp.linalg.norm(grads[:, -3:], axis=-1)
    weight = jnp.where(jnp.abs(y) < NEAR_FIELD, near_weight, 1.0)
    weight = weight / jnp.mean(weight)
    return {
        "distance": jnp.mean(weight * (pred - y) ** 2),
        "eikonal": jnp.mean((grad_norm - 1.0) ** 2),
        "over": jnp.mean(weight * jnp.maximum(model_cfg.head(pred) - jnp.abs(y), 0.0) ** 2),
    }


def epoch_order(key, n_samples: int, batch_size: int) -> np.ndarray:
    """An epoch's minibatches of sample indices (n_samples // batch_size, batch_size), int32.

    A permutation drawn on the host by numpy's PCG64 seeded with the key's bits: XLA's sort-based
    ``jax.random.permutation`` takes seconds for millions of samples on a CPU, numpy a tenth of one.
    """
    n_batches = n_samples // batch_size
    order = np.random.default_rng(np.asarray(jax.random.key_data(key))).permutation(n_samples)
    return order[: n_batches * batch_size].astype(np.int32).reshape(n_batches, batch_size)


def make_step(model_cfg: ModelConfig, cfg: TrainConfig, optimizer: optax.GradientTransformation):
    """One optimiser step on a minibatch, in ``lax.scan``'s form:
    step((params, opt_state), (x (B, D), y (B,))) -> ((params, opt_state), loss terms)."""

    def total(params, xb, yb):
        t = loss_terms(params, model_cfg, xb, yb, cfg.near_weight)
        return t["distance"] + cfg.lambda_eikonal * t["eikonal"] + cfg.lambda_over * t["over"], t

    def step(carry, batch):
        params, opt_state = carry
        (_, terms), grads = jax.value_and_grad(total, has_aux=True)(params, *batch)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), terms

    return step


def make_epoch(model_cfg: ModelConfig, cfg: TrainConfig, optimizer: optax.GradientTransformation, n_samples: int):
    """An epoch: shuffle (:func:`epoch_order`), then a jitted ``lax.scan`` of :func:`make_step` over full
    minibatches.

    The samples are gathered in the epoch's order once, so each step reads its minibatch
    contiguously instead of gathering it from the whole set.

    Returns:
      epoch(params, opt_state, key, x (S, D), y (S,)) -> (params, opt_state, mean loss terms)
    """
    step = make_step(model_cfg, cfg, optimizer)

    @jax.jit
    def scan(params, opt_state, order, x, y):
        (params, opt_state), terms = jax.lax.scan(step, (params, opt_state), (x[order], y[order]))
        return params, opt_state, jax.tree_util.tree_map(jnp.mean, terms)

    def epoch(params, opt_state, key, x, y):
        return scan(params, opt_state, epoch_order(key, n_samples, cfg.batch_size), x, y)

    return epoch


def predict_dataset(model: NCEDF, data: LinkDataset) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Predictions on a set's points (N, K) and surface points (N, S)."""
    per_config = jax.jit(jax.vmap(model.link_distance))
    return per_config(jnp.asarray(data.points), data.theta, data.phi), per_config(
        jnp.asarray(data.surface), data.theta, data.phi
    )


def evaluate_model(model: NCEDF, data: LinkDataset) -> dict:
    """distance_metrics of ``model`` on a validation set (its near field in proportion to the link)."""
    pred, surface = predict_dataset(model, data)
    return distance_metrics(pred, data.distances, surface, NEAR_FIELD * unit(model.spec))


def initial_state(model_cfg: ModelConfig, cfg: TrainConfig, optimizer: optax.GradientTransformation) -> TrainState:
    """A fresh run's state: parameters and key from ``cfg.seed``, no epoch done."""
    key, k_init = jax.random.split(jax.random.PRNGKey(cfg.seed))
    params = init_params(k_init, model_cfg)
    return TrainState(0, params, optimizer.init(params), key)


def train(
    model_cfg: ModelConfig,
    cfg: TrainConfig,
    data: LinkDataset,
    val: LinkDataset,
    spec: RobotSpec,
    progress: bool = True,
    domain: tuple = (BOX_MIN, BOX_MAX),
    on_epoch=None,
    resume=None,
) -> tuple[NCEDF, list[dict]]:
    """Train a link network; returns the model and per-epoch history.

    ``domain`` is the box (link frame, m) the training points cover;
    ``on_epoch(row, state)``, if given, receives each epoch's history row and the
    :class:`ncedf.train_state.TrainState` after it (to save); ``resume(template)``, if given, returns
    the state to go on from (or None to start afresh) given a fresh run's first state.
    """
    x, y = training_arrays(data, model_cfg)
    n = int(y.shape[0])
    if n < cfg.batch_size:
        raise ValueError(f"the training set has {n} samples, fewer than batch_size {cfg.batch_size}")
    optimizer = make_optimizer(cfg, cfg.epochs * (n // cfg.batch_size))
    state = initial_state(model_cfg, cfg, optimizer)
    if resume is not None:
        state = resume(state) or state
    epoch = make_epoch(model_cfg, cfg, optimizer, n)
    bar = tqdm(range(state.epoch, cfg.epochs), desc="train", unit="epoch", disable=not progress, file=sys.stderr,
               initial=state.epoch, total=cfg.epochs)
    for i in bar:
        key, k_epoch = jax.random.split(state.key)
        start = time.perf_counter()
        params, opt_state, terms = epoch(state.params, state.opt_state, k_epoch, x, y)
        terms = {k: float(v) for k, v in terms.items()}
        seconds = time.perf_counter() - start
        metrics = evaluate_model(NCEDF(params=params, config=model_cfg, spec=spec, domain=domain), val)
        row = {"epoch": i + 1, "seconds": seconds, "samples_per_second": n / seconds, **terms, **metrics}
        state = TrainState(i + 1, params, opt_state, key, state.history + (row,))
        if on_epoch is not None:
            on_epoch(row, state)
        bar.set_postfix(mae=f"{metrics['mae']:.4f}", moe=f"{metrics['moe']:.4f}", near_mae=f"{metrics['near_mae']:.4f}")
    return NCEDF(params=state.params, config=model_cfg, spec=spec, domain=domain), list(state.history)


def _output_problem(stem: Path, overwrite: bool) -> str | None:
    """Why the weights cannot be written to ``stem``.msgpack/.json, checked before training."""
    from recorder import RecorderError
    from recorder.recorder import check_writable

    stem = stem.with_suffix("")
    try:
        check_writable({kind: stem.with_suffix(f".{kind}") for kind in ("msgpack", "json")}, overwrite, "weights")
    except RecorderError as exc:
        return str(exc)
    return None


def parse_args(argv=None) -> argparse.Namespace:
    from recorder.cli import OneLineParser, non_negative, path_text, positive

    p = OneLineParser(prog="python -m ncedf.train", description=__doc__.split("\n\n")[0])
    model, train, data, val, robot = ModelConfig(), TrainConfig(), DatasetConfig(), ValidationConfig(), RobotSpec(1)
    p.add_argument("--layers", type=positive, default=model.layers,
                   help=f"Dense layers incl. output (default {model.layers})")
    p.add_argument("--width", type=positive, default=model.width, help=f"hidden width (default {model.width})")
    p.add_argument("--encoding", choices=ENCODINGS, default=model.encoding)
    p.add_argument("--output", choices=OUTPUTS, default=model.output, metavar="KIND",
                   help="distance (the network is the distance: the paper's) or signed-abs (|its signed distance|, "
                        "default)")
    p.add_argument("--epochs", type=positive, default=train.epochs)
    p.add_argument("--batch-size", type=positive, default=train.batch_size)
    p.add_argument("--lr", type=float, default=train.learning_rate, help="peak learning rate")
    p.add_argument("--schedule", choices=SCHEDULES, default=train.schedule)
    p.add_argument("--lambda-eikonal", type=float, default=train.lambda_eikonal)
    p.add_argument("--lambda-over", type=float, default=train.lambda_over)
    p.add_argument("--near-weight", type=float, default=train.near_weight,
                   help="loss weight of near-field samples (beyond the paper)")
    p.add_argument("--no-overestimation", action="store_true", help="drop the over-estimation loss (paper Table II)")
    p.add_argument("--labels", choices=("exact", "surface-samples"), default=data.labels)
    p.add_argument("--configs", type=positive, default=data.n_configs, help="training configurations N")
    p.add_argument("--grid", type=positive, default=data.grid, help="workspace grid points per axis")
    p.add_argument("--surface", type=non_negative, default=data.n_surface, help="surface points per configuration")
    p.add_argument("--near", type=non_negative, default=data.n_near, help="extra near-surface points per configuration")
    p.add_argument("--val-configs", type=positive, default=val.n_configs)
    p.add_argument("--val-points", type=positive, default=val.n_points)
    p.add_argument("--length", type=float, default=robot.length,
                   help=f"link backbone length L, m (default {robot.length:g}, the paper's)")
    p.add_argument("--radius", type=float, nargs="+", default=[robot.radius], metavar="R",
                   help=f"link radius, m (default {robot.radius:g}); one per link from the base: a tapered robot")
    p.add_argument("--arc-min", type=float, default=robot.l_min,
                   help=f"shortest chamber arc length, m (default {robot.l_min:g})")
    p.add_argument("--arc-max", type=float, default=robot.l_max,
                   help=f"longest chamber arc length, m (default {robot.l_max:g})")
    p.add_argument("--seed", type=int, default=train.seed)
    p.add_argument("--out", type=path_text, required=True, help="output stem: writes OUT.msgpack and OUT.json")
    p.add_argument("--record", type=path_text, metavar="STEM",
                   help="also record the run (per-epoch /metrics) to STEM.rrd and STEM.mcap")
    p.add_argument("--overwrite", action="store_true", help="overwrite existing weights and recording")
    add_cache_option(p)
    return p.parse_args(argv)


def _configs(args):
    """The robot (one link), model, training, dataset and validation configs of the parsed arguments
    (ValueError names a bad one). The training set is of the link in reference units, the validation
    set of the link itself (``ncedf.units``)."""
    spec = RobotSpec(len(args.radius), args.length, tuple(args.radius), args.arc_min, args.arc_max)
    model_cfg = ModelConfig(args.layers, args.width, args.encoding, args.output)
    cfg = TrainConfig(
        epochs=args.epochs,
        batch_size=args.batch_size,
        learning_rate=args.lr,
        schedule=args.schedule,
        lambda_eikonal=args.lambda_eikonal,
        lambda_over=0.0 if args.no_overestimation else args.lambda_over,
        near_weight=args.near_weight,
        seed=args.seed,
    )
    data_cfg = DatasetConfig(
        n_configs=args.configs, grid=args.grid, n_surface=args.surface, n_near=args.near,
        labels=args.labels, seed=args.seed,
    )
    u = unit(spec)
    val_cfg = ValidationConfig(n_configs=args.val_configs, n_points=args.val_points,
                               box_min=tuple(u * v for v in BOX_MIN), box_max=tuple(u * v for v in BOX_MAX))
    return spec, model_cfg, cfg, data_cfg, val_cfg


def worst_metrics(per_link: list) -> dict:
    """A tapered robot's summary metrics: the worst link's value of each (the largest error)."""
    return {k: max(m[k] for m in per_link) for k in per_link[0]}


def train_links(spec: RobotSpec, model_cfg, cfg, data_cfg, val_cfg, on_epoch=None):
    """Train every distinct link of ``spec`` (one, or each link of a tapered robot).

    Returns the parameters (stacked per link for a tapered robot), the training sets, the
    validation sets, the per-link histories and the seconds spent making the data.
    """
    links = [spec.link(i) for i in range(spec.n_links)] if spec.tapered else [model_spec(spec)]
    params, data, val, history, data_seconds = [], [], [], [], 0.0
    for link in links:
        start = time.perf_counter()
        data.append(load_dataset(data_cfg, to_reference(link)))
        val.append(load_dataset(val_cfg, link))
        data_seconds += time.perf_counter() - start
        model, rows = train(model_cfg, cfg, data[-1], val[-1], link, domain=(val_cfg.box_min, val_cfg.box_max),
                            on_epoch=on_epoch)
        params.append(model.params)
        history.append(rows)
    return (stack_links(params) if spec.tapered else params[0]), data, val, history, data_seconds


def _one(values: list):
    """A list of per-link values as the metadata keeps it: the value itself for one link."""
    return values[0] if len(values) == 1 else values


def main(argv=None) -> int:
    args = parse_args(argv)
    enable_compile_cache(not args.no_cache)
    try:
        spec, model_cfg, cfg, data_cfg, val_cfg = _configs(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    problem = _output_problem(Path(args.out), args.overwrite)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    settings = {
        "training": dataclasses.asdict(cfg),
        "dataset": dataclasses.asdict(data_cfg),
        "validation": dataclasses.asdict(val_cfg),
    }
    recording = contextlib.nullcontext()
    if args.record:
        from recorder import Recorder, RecorderError

        meta = {"scenario": "training", "architecture": dataclasses.asdict(model_cfg), **settings,
                "robot": dataclasses.asdict(spec), "jax_version": jax.__version__}
        try:
            recording = Recorder(args.record, meta, overwrite=args.overwrite)
        except RecorderError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    from recorder.cli import EXIT_STATUS, Stopped, stop_on_signals

    try:
        with stop_on_signals(), recording as rec:
            start = time.perf_counter()
            logged = []

            def record(row, _):  # epochs of every link in turn, numbered on
                logged.append(row)
                if rec is not None:
                    rec.log_step(len(logged), float(len(logged)),
                                 metrics={k: float(v) for k, v in row.items() if k != "epoch"})

            params, data, val, history, data_seconds = train_links(spec, model_cfg, cfg, data_cfg, val_cfg, record)
            train_seconds = time.perf_counter() - start - data_seconds
            if rec is not None:
                rec.finish({"outcome": "success", "steps": len(logged)})
    except Stopped as stop:
        kept = f"; the recording {args.record} is kept, marked interrupted" if args.record else ""
        print(f"stopped by {stop}: no model written{kept}", file=sys.stderr)
        return EXIT_STATUS[stop.signum]
    per_link = [{k: v for k, v in rows[-1].items() if k not in ("epoch", "seconds", "samples_per_second")}
                for rows in history]
    metrics = worst_metrics(per_link)
    extra = {
        "command": "python -m ncedf.train " + " ".join(sys.argv[1:] if argv is None else argv),
        **settings,
        "dataset": {**settings["dataset"], "hash": _one([d.key for d in data]),
                    "samples": sum(d.n_samples for d in data)},
        "validation": {**settings["validation"], "hash": _one([v.key for v in val])},
        "metrics": metrics,
        **({"link_metrics": per_link} if spec.tapered else {}),
        "train_seconds": round(train_seconds, 1),
        "history": _one([[{k: round(v, 6) for k, v in row.items()} for row in rows] for rows in history]),
        "jax_version": jax.__version__,
    }
    weights, meta = save_model(args.out, params, model_cfg, spec, extra, (val_cfg.box_min, val_cfg.box_max))
    print(f"trained in {train_seconds:.0f} s ({data_seconds:.0f} s data); wrote {weights} and {meta}")
    shown = ("mae", "rmse", "moe", "over_p999", "near_mae", "near_moe", "surface_mean")
    print("  ".join(f"{k}={metrics[k]:.4f}" for k in shown))
    return 0


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
