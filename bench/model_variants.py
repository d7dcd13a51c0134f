"""Accuracy of N-CEDF variants trained with the same budget (paper Tables I-II and beyond).

Trains each variant for ``--epochs`` on the same data and prints the
validation metrics against exact distances: the paper's input encoding
against the bending-plane encoding, the plain distance output against the
absolute value of a learned signed distance, with and without the
over-estimation loss, and the shipped recipe (near-surface samples and
weights).

    python bench/model_variants.py --epochs 4
"""

from __future__ import annotations

import time

from ncedf.data import DatasetConfig, ValidationConfig, load_dataset
from ncedf.model import ModelConfig
from ncedf.robot import RobotSpec
from ncedf.train import TrainConfig, train
from recorder.cli import OneLineParser, exit_with, stoppable

from arguments import positive

# name -> (model settings, train settings, extra near-surface points)
VARIANTS = {
    "paper encoding, distance output": (dict(encoding="paper", output="distance"), {}, 0),
    "  same, no over-estimation loss": (dict(encoding="paper", output="distance"), dict(lambda_over=0.0), 0),
    "bending-plane, distance output": (dict(encoding="bending-plane", output="distance"), {}, 0),
    "bending-plane, signed-abs": (dict(encoding="bending-plane", output="signed-abs"), {}, 0),
    "shipped recipe (+near samples, weights)": (
        dict(encoding="bending-plane", output="signed-abs"), dict(near_weight=5.0, lambda_over=10.0), 4096),
}
COLUMNS = ("mae", "rmse", "moe", "over_p999", "near_mae", "near_moe", "surface_mean")


def main() -> None:
    p = OneLineParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--epochs", type=positive, default=4)
    p.add_argument("--layers", type=positive, default=4)
    p.add_argument("--width", type=positive, default=16)
    p.add_argument("--only", nargs="+", metavar="TEXT", help="substrings of the names of the variants to run")
    args = p.parse_args()
    chosen = [name for name in VARIANTS if not args.only or any(s and s in name for s in args.only)]
    if not chosen:
        p.error(f"--only: no variant's name holds {' or '.join(map(repr, args.only))}; "
                f"the variants: {', '.join(VARIANTS)}")
    spec, checked = RobotSpec(1), ValidationConfig()
    val = load_dataset(checked, spec)
    print(f"{args.layers} x {args.width}, {args.epochs} epochs each, validation {checked.n_configs} x "
          f"{checked.n_points} exact labels")
    print(f"{'variant':42s} " + " ".join(f"{c:>12s}" for c in COLUMNS) + "   train s")
    for name in chosen:
        model_kw, train_kw, near = VARIANTS[name]
        data = load_dataset(DatasetConfig(n_near=near), spec)
        start = time.perf_counter()
        _, history = train(ModelConfig(args.layers, args.width, **model_kw),
                           TrainConfig(epochs=args.epochs, **train_kw), data, val, spec, progress=False)
        m = history[-1]
        print(f"{name:42s} " + " ".join(f"{m[c]:12.4f}" for c in COLUMNS) + f"   {time.perf_counter() - start:7.0f}",
              flush=True)


if __name__ == "__main__":
    exit_with(stoppable(main))
