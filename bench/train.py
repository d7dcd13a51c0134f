"""Training throughput and accuracy: the epoch against the former one, same data, same run.

The epoch (``ncedf.train.make_epoch``) shuffles on the host and gathers the set once in that
order; the reference is the former epoch, which drew the permutation with XLA's sort-based
``jax.random.permutation`` and gathered each minibatch inside the scan. Both train the same
network from the same initial weights for the same epochs; the bench prints samples per second
(median over the epochs after the first, which compiles) and each one's losses and validation
metrics at the end.

    python bench/train.py [--layers 4 --width 16 --epochs 3]
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.data import DatasetConfig, ValidationConfig, load_dataset
from ncedf.model import ENCODINGS, NCEDF, ModelConfig, model_spec
from ncedf.robot import RobotSpec
from ncedf.train import (TrainConfig, evaluate_model, initial_state, make_epoch, make_optimizer, make_step,
                         training_arrays)
from recorder.cli import OneLineParser, exit_with, stoppable

from arguments import non_negative, positive


def former_epoch(model_cfg: ModelConfig, cfg: TrainConfig, optimizer, n_samples: int):
    """The reference: the permutation drawn by XLA and each minibatch gathered inside the scan."""
    n_batches = n_samples // cfg.batch_size
    step = make_step(model_cfg, cfg, optimizer)

    @jax.jit
    def epoch(params, opt_state, key, x, y):
        order = jax.random.permutation(key, n_samples)[: n_batches * cfg.batch_size]
        (params, opt_state), terms = jax.lax.scan(lambda carry, idx: step(carry, (x[idx], y[idx])),
                                                  (params, opt_state), order.reshape(n_batches, -1))
        return params, opt_state, jax.tree_util.tree_map(jnp.mean, terms)

    return epoch


def run(name, make, model_cfg, cfg, spec, x, y, val):
    """Train with the epoch ``make`` builds; print its rate, final losses and validation metrics."""
    n = int(y.shape[0])
    optimizer = make_optimizer(cfg, cfg.epochs * (n // cfg.batch_size))
    state = initial_state(model_cfg, cfg, optimizer)
    epoch, key, params, opt_state = make(model_cfg, cfg, optimizer, n), state.key, state.params, state.opt_state
    seconds = []
    for _ in range(cfg.epochs):
        key, k_epoch = jax.random.split(key)
        start = time.perf_counter()
        params, opt_state, terms = jax.block_until_ready(epoch(params, opt_state, k_epoch, x, y))
        seconds.append(time.perf_counter() - start)
    metrics = evaluate_model(NCEDF(params=params, config=model_cfg, spec=spec), val)
    rate = n / np.median(seconds[1:])
    print(f"{name:>9}: {rate / 1e6:.3f} M samples/s (epochs {', '.join(f'{s:.1f}' for s in seconds)} s; "
          f"the first compiles)")
    print(f"{'':>9}  losses " + ", ".join(f"{k} {float(v):.5f}" for k, v in terms.items())
          + "; validation " + ", ".join(f"{k} {metrics[k]:.4f}" for k in ("mae", "moe", "near_mae")))
    return rate


def main() -> None:
    p = OneLineParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--layers", type=positive, default=4)
    p.add_argument("--width", type=positive, default=16)
    p.add_argument("--encoding", choices=ENCODINGS, default="bending-plane")
    p.add_argument("--epochs", type=positive, default=3, help="epochs each (at least 2: the first compiles)")
    p.add_argument("--near", type=non_negative, default=4096, help="near-surface points per configuration")
    args = p.parse_args()
    if args.epochs < 2:
        p.error(f"--epochs must be at least 2 (the first compiles), got {args.epochs}")

    spec, model_cfg = model_spec(RobotSpec(1)), ModelConfig(args.layers, args.width, args.encoding)
    cfg = TrainConfig(epochs=args.epochs)
    x, y = training_arrays(load_dataset(DatasetConfig(n_near=args.near), spec), model_cfg)
    val = load_dataset(ValidationConfig(), spec)
    print(f"{args.layers} layers x {args.width}, {args.encoding}; {int(y.shape[0]):,} samples per epoch, "
          f"batch {cfg.batch_size}; devices: {jax.devices()}")
    rate = run("epoch", make_epoch, model_cfg, cfg, spec, x, y, val)
    ref = run("reference", former_epoch, model_cfg, cfg, spec, x, y, val)
    print(f"epoch / reference speed: {rate / ref:.2f}x")
    print(f"settings: {dataclasses.asdict(cfg)}")


if __name__ == "__main__":
    exit_with(stoppable(main))
