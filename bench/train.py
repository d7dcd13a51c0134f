"""Training throughput: epoch time and samples per second.

Compares the jitted epoch (one ``lax.scan`` over all minibatches) with a
reference loop that calls a jitted single-minibatch step from Python, on the
same data, in the same run.

    python bench/train.py [--layers 4 --width 16 --epochs 2 --ref-batches 2000]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import numpy as np
import optax

from ncedf.data import DatasetConfig, load_dataset
from ncedf.model import ENCODINGS, ModelConfig, init_params
from ncedf.robot import RobotSpec
from ncedf.train import TrainConfig, loss_terms, make_epoch, make_optimizer, training_arrays


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--layers", type=int, default=4)
    p.add_argument("--width", type=int, default=16)
    p.add_argument("--encoding", choices=ENCODINGS, default="bending-plane")
    p.add_argument("--epochs", type=int, default=2, help="timed epochs (after one compile epoch)")
    p.add_argument("--near", type=int, default=4096, help="near-surface points per configuration")
    p.add_argument("--ref-batches", type=int, default=2000, help="minibatches timed for the Python-loop reference")
    args = p.parse_args()

    spec = RobotSpec(1)
    model_cfg = ModelConfig(args.layers, args.width, args.encoding)
    cfg = TrainConfig(epochs=args.epochs + 1)
    data = load_dataset(DatasetConfig(n_near=args.near), spec)
    x, y = training_arrays(data, model_cfg)
    n = int(y.shape[0])
    n_batches = n // cfg.batch_size
    optimizer = make_optimizer(cfg, cfg.epochs * n_batches)
    params = init_params(jax.random.PRNGKey(0), model_cfg)
    opt_state = optimizer.init(params)
    print(f"{args.layers} layers x {args.width}, {args.encoding}; {n:,} samples per epoch, "
          f"batch {cfg.batch_size}; devices: {jax.devices()}")

    epoch = make_epoch(model_cfg, cfg, optimizer, n)
    start = time.perf_counter()
    params, opt_state, _ = epoch(params, opt_state, jax.random.PRNGKey(1), x, y)
    jax.block_until_ready(params)
    print(f"first epoch (with compile): {time.perf_counter() - start:.1f} s")
    times = []
    for i in range(args.epochs):
        start = time.perf_counter()
        params, opt_state, _ = epoch(params, opt_state, jax.random.PRNGKey(2 + i), x, y)
        jax.block_until_ready(params)
        times.append(time.perf_counter() - start)
    scan_rate = n / np.median(times)
    print(f"scan epoch: median {np.median(times):.2f} s per epoch, {scan_rate / 1e6:.3f} M samples/s")

    @jax.jit
    def step(params, opt_state, xb, yb):
        def total(p):
            t = loss_terms(p, model_cfg, xb, yb, cfg.near_weight)
            return t["distance"] + cfg.lambda_eikonal * t["eikonal"] + cfg.lambda_over * t["over"]

        grads = jax.grad(total)(params)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state

    order = np.asarray(jax.random.permutation(jax.random.PRNGKey(9), n))
    batches = min(args.ref_batches, n_batches)
    xb, yb = x[order[: cfg.batch_size]], y[order[: cfg.batch_size]]
    jax.block_until_ready(step(params, opt_state, xb, yb))
    start = time.perf_counter()
    for b in range(batches):
        idx = order[b * cfg.batch_size:(b + 1) * cfg.batch_size]
        params, opt_state = step(params, opt_state, x[idx], y[idx])
    jax.block_until_ready(params)
    ref_rate = batches * cfg.batch_size / (time.perf_counter() - start)
    print(f"reference (Python loop over a jitted step, {batches} batches): {ref_rate / 1e6:.3f} M samples/s, "
          f"{n / ref_rate:.1f} s per epoch")
    print(f"scan / reference speed: {scan_rate / ref_rate:.2f}x")
    print(f"settings: {dataclasses.asdict(cfg)}")


if __name__ == "__main__":
    main()
