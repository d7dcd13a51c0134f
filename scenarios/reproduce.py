"""The experiments behind the paper's Tables I-IV, written as recordings for ``analysis/``.

    python -m scenarios.reproduce {table1,table2,table3,table4,timing,worlds,all} --out runs/ [--quick]

Each table has its folder under ``--out`` (``table1`` ... ``table4``; with
``--quick`` ``table1-quick`` ...), holding one recording per network or episode
and ``experiment.mcap``, whose ``/run`` metadata names the experiment, its
settings, whether it is quick, the command, the date, the machine and the
package versions (quick results are marked there and in every table).

* Table I: the 12 networks (2-5 layers x width 16/24/32), both input encodings,
  trained with ``ncedf.train`` on exact labels for an epoch budget
  (``--epochs``, default the paper's 100). A network's recording names the
  machine that trained and timed it and holds one ``/metrics`` row per epoch
  (loss terms, validation MAE, RMSE, MOE, p99.9 over-estimation on exact
  distances), then ``--timing-repeats`` rows of
  timings: ``inference_ms`` (whole-robot distance, one 4-link configuration,
  500 points) and ``mppi_step_ms`` (4 links, 800 samples, horizon 20, the
  cluttered scene's ~500 observed points). Weights are saved beside it.
* Table II: 4 x 16 with and without the over-estimation loss, recorded the same way.
* Table III: the dynamic-sphere sweep, shapes ncedf, spheres, pointcloud:1000,
  pointcloud:5000 x every controller of ``ncedf.presets.PRESETS``
  (``--envs`` environments; ``--envs-5000`` for pointcloud:5000), then the floor's verdict
  (``scenarios.floor``) on every environment no episode solved.
* Table IV: cluttered, 4 / 5 / 7 links x ``--seeds`` controller seeds x ``--env-seeds`` environment
  seeds (the observed points) x every controller.
* worlds (beyond the paper's): the charging port and the confined-space runners (window, cabinet,
  pipe, slot, pillars), 4 / 5 / 7 links x ``--env-seeds`` environment seeds x ours and paper (the
  solver-time reference, at the same rollouts and horizon).
* timing (the MPPI time figures): one step of the paper's controller (800 samples, horizon 20) per
  representation, against link count (4 / 5 / 7 at 500 points) and obstacle points (100 ... 5000 at
  4 links), ``--timing-repeats`` timed steps each, recorded as ``solver_ms`` rows.

Tables III and IV and the worlds run through ``scenarios.sweep.run_sweep``, in local processes or
on Ray (``--executor ray [--address ADDR]``, the optional extra ``ncedf[cluster]``). Everything resumes:
a network or episode whose recording is closed with a final outcome is skipped, and a network
stopped midway goes on from its last finished epoch (its training state is saved after each), so
the same command finishes an interrupted experiment.

``--quick`` shrinks every experiment (Table I: 2 and 4 layers x width 16, both
encodings, 1 epoch on a 20-configuration, 12^3-grid set; 64 MPPI samples,
horizon 8, 10 steps; one environment or seed; timing: 3 representations at 4 / 7
links and 250 / 1000 points) so that
``all --quick`` runs in a small fraction of the full budget's time; its numbers only show the pipeline works.

Ctrl-C / SIGTERM: the network being trained is recorded as interrupted (the
next run goes on from its last epoch), complete recordings are kept; exit 130 / 143.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import sys
import time
from pathlib import Path

from scenarios import manifest

#: Table I grid (paper): Dense layers incl. output x hidden width.
LAYERS = (2, 3, 4, 5)
WIDTHS = (16, 24, 32)
#: Table II network.
TABLE2_NETWORK = (4, 16)
#: Table III representations.
TABLE3_SHAPES = ("ncedf", "spheres", "pointcloud:1000", "pointcloud:5000")
#: Table IV link counts.
TABLE4_LINKS = (4, 5, 7)
#: Timing setting of Table I (paper Sec. VI-B): links, MPPI samples, horizon.
TIMING_LINKS, TIMING_SAMPLES, TIMING_HORIZON = 4, 800, 20
#: Timing figure: representations, link counts (at ``ncedf.evaluate.INFERENCE_POINTS`` points), point counts
#: (at 4 links).
TIMING_SHAPES = TABLE3_SHAPES
TIMING_LINK_COUNTS = (4, 5, 7)
TIMING_POINT_COUNTS = (100, 250, 500, 1000, 2000, 5000)
TABLES = ("table1", "table2", "table3", "table4", "worlds", "timing")
#: The controllers run in the worlds beyond the paper's (``scenarios.WORLDS``).
WORLD_CONTROLLERS = ("ours", "paper")
PAPER_EPOCHS = 100
#: Beside a network's recording while it trains: its training state after the last epoch done.
STATE_SUFFIX = ".state.msgpack"


@dataclasses.dataclass(frozen=True)
class NetworkBudget:
    """Tables I and II: ``epochs`` per network; the training set (``configs`` configurations,
    ``grid`` points per axis, ``surface`` points); the validation set (``val_configs``, ``val_points``,
    ``val_surface``); the grid of ``layers`` and ``widths``."""

    epochs: int = PAPER_EPOCHS
    configs: int = 250
    grid: int = 32
    surface: int = 1600
    val_configs: int = 100
    val_points: int = 4096
    val_surface: int = 256
    layers: tuple[int, ...] = LAYERS
    widths: tuple[int, ...] = WIDTHS


@dataclasses.dataclass(frozen=True)
class TimingBudget:
    """The timings: ``repeats`` timed calls per network or case (after compilation), the MPPI step's
    ``samples`` and ``horizon``, and the timing experiment's grid (``shapes`` by ``links`` at
    ``ncedf.evaluate.INFERENCE_POINTS`` points, and by ``points`` at ``TIMING_LINKS`` links)."""

    repeats: int = 20
    samples: int = TIMING_SAMPLES
    horizon: int = TIMING_HORIZON
    shapes: tuple[str, ...] = TIMING_SHAPES
    links: tuple[int, ...] = TIMING_LINK_COUNTS
    points: tuple[int, ...] = TIMING_POINT_COUNTS


@dataclasses.dataclass(frozen=True)
class EpisodeBudget:
    """The episodes: Table III ``envs`` (``envs_5000`` for pointcloud:5000), Table IV's controller
    ``seeds``, the ``env_seeds`` of Table IV and the worlds, overrides of every episode's ``samples``,
    ``horizon`` and ``max_steps`` (None: the controller's and scenario's), and sweep ``workers`` (None:
    one per core)."""

    envs: int = 200
    envs_5000: int = 50
    seeds: int = 20
    env_seeds: int = 10
    samples: int | None = None
    horizon: int | None = None
    max_steps: int | None = None
    workers: int | None = None


@dataclasses.dataclass(frozen=True)
class Budget:
    """How big each experiment is; ``quick``: a smoke-sized run."""

    networks: NetworkBudget = NetworkBudget()
    timing: TimingBudget = TimingBudget()
    episodes: EpisodeBudget = EpisodeBudget()
    quick: bool = False


QUICK = Budget(
    NetworkBudget(epochs=1, configs=20, grid=12, surface=200, val_configs=10, val_points=512, val_surface=32,
                  layers=(2, 4), widths=(16,)),
    TimingBudget(repeats=3, samples=64, horizon=8, shapes=("ncedf", "spheres", "pointcloud:1000"), links=(4, 7),
                 points=(250, 1000)),
    EpisodeBudget(envs=1, envs_5000=1, seeds=1, env_seeds=1, samples=64, horizon=8, max_steps=10),
    quick=True)


def folder(out: Path, table: str, budget: Budget) -> Path:
    """The folder of one table's recordings."""
    return Path(out) / (f"{table}-quick" if budget.quick else table)


def write_manifest(where: Path, table: str, budget: Budget, command: str, settings: dict) -> None:
    """``experiment.mcap`` of ``table`` (``scenarios.manifest``), with the budget and whether it is quick."""
    manifest.write_manifest(where, table, command, settings, quick=budget.quick, budget=dataclasses.asdict(budget))


# ---------------------------------------------------------------- Tables I and II: networks
@dataclasses.dataclass(frozen=True)
class Network:
    """One network of Table I or II."""

    layers: int
    width: int
    encoding: str
    lambda_over: float

    @property
    def name(self) -> str:
        return f"net_{self.encoding}_{self.layers}x{self.width}_lo{self.lambda_over:g}"


def networks(table: str, budget: Budget) -> list[Network]:
    from ncedf.model import ENCODINGS
    from ncedf.train import TrainConfig

    if table == "table1":
        return [Network(l, w, e, TrainConfig.lambda_over) for e in ENCODINGS for l in budget.networks.layers
                for w in budget.networks.widths]
    layers, width = TABLE2_NETWORK
    from ncedf.model import ModelConfig

    return [Network(layers, width, ModelConfig.encoding, lo) for lo in (TrainConfig.lambda_over, 0.0)]


def timing_points(n_points: int, seed: int = 0):
    """``n_points`` obstacle points like the cluttered scene's observed cloud at t = 0 (about 500 points on
    its boxes and spheres): its first points, or, for more, its points drawn again with 2 cm jitter. (P, 3) float32."""
    import numpy as np

    from scenarios.episode import EpisodeSettings, build_scene

    scene = build_scene(EpisodeSettings("cluttered", TIMING_LINKS, 0))
    points = np.asarray(scene.observer.observe(0.0), dtype=np.float32)
    if n_points <= len(points):
        return points[:n_points]
    rng = np.random.default_rng(seed)
    extra = points[rng.integers(0, len(points), n_points - len(points))]
    return np.concatenate([points, extra + rng.normal(0.0, 0.02, extra.shape).astype(np.float32)])


def mppi_step_ms(model, points, budget: Budget, seed: int = 0, shape: str = "ncedf",
                 links: int = TIMING_LINKS) -> list[float]:
    """Wall times (ms) of ``budget.timing.repeats`` MPPI steps after compilation from the straight state
    towards the cluttered scene's goal (``model``: the N-CEDF for shape ncedf, else unused)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ncedf.controller import Controller
    from ncedf.presets import Observation, preset
    from ncedf.robot import RobotSpec
    from ncedf.shapes import make_shape
    from scenarios.cluttered import GOAL

    spec = RobotSpec(links)
    config = preset("paper", spec, Observation(len(points)), samples=budget.timing.samples,
                    horizon=budget.timing.horizon)
    mppi = Controller(spec, make_shape(shape, spec, model=model) if shape == "ncedf" else make_shape(shape, spec),
                      config)
    state = mppi.init(jax.random.PRNGKey(seed))
    arc = jnp.asarray(spec.straight_state(), jnp.float32)
    goal = jnp.asarray(GOAL, jnp.float32)
    jax.block_until_ready(mppi.step(state, arc, goal, points))
    times = []
    for _ in range(budget.timing.repeats):
        start = time.perf_counter()
        action, state, _ = jax.block_until_ready(mppi.step(state, arc, goal, points))
        times.append(1e3 * (time.perf_counter() - start))
        arc = arc + np.asarray(action) * config.mppi.dt
    return times


def inference_times_ms(model, points, repeats: int, seed: int = 0) -> list[float]:
    """Wall times (ms) of the whole-robot distance of one 4-link configuration to ``points``."""
    import jax

    from ncedf import evaluate
    from ncedf.robot import RobotSpec, sample_arc_lengths

    spec = RobotSpec(TIMING_LINKS, **model.spec.link_geometry())
    arc = sample_arc_lengths(jax.random.PRNGKey(seed), spec, (TIMING_LINKS,))
    return evaluate.inference_times_ms(model, points, arc, repeats)


def log_epoch(rec, row: dict) -> None:
    """One epoch's history row as a recording's step."""
    rec.log_step(row["epoch"], float(row["epoch"]), metrics={k: float(v) for k, v in row.items() if k != "epoch"})


def train_network(net: Network, where: Path, budget: Budget, data, val, points, seed: int) -> None:
    """Train, evaluate and time one network; record it to ``where/<net.name>.mcap``, weights beside it.
    After each epoch the training state is saved beside them (``STATE_SUFFIX``), so a run stopped
    midway (Ctrl-C, a kill) goes on from its last epoch, with the floats of a run never stopped."""
    from ncedf.model import ModelConfig, save_model
    from ncedf.robot import RobotSpec
    from ncedf.train import TrainConfig, train
    from ncedf.train_state import load_state, save_state
    from recorder import Recorder

    spec = RobotSpec(n_links=1)
    model_cfg = ModelConfig(net.layers, net.width, net.encoding)
    cfg = TrainConfig(epochs=budget.networks.epochs, lambda_over=net.lambda_over, seed=seed)
    meta = {"run_id": f"{where.name}/{net.name}", "scenario": "training",
            "experiment": where.name.removesuffix("-quick"), "quick": budget.quick,
            "network": dataclasses.asdict(net), "architecture": dataclasses.asdict(model_cfg),
            "training": dataclasses.asdict(cfg), "dataset": {"hash": data.key, "samples": data.n_samples},
            "validation": {"hash": val.key, "samples": int(val.distances.size)},
            "timing": {"links": TIMING_LINKS, "inference_points": int(len(points)),
                       "mppi_samples": budget.timing.samples, "mppi_horizon": budget.timing.horizon,
                       "mppi_points": int(len(points)), "repeats": budget.timing.repeats}}
    saved, fingerprint = where / f"{net.name}{STATE_SUFFIX}", json.dumps(meta, sort_keys=True)
    meta["machine"] = manifest.machine()  # not in the fingerprint: a run stopped on one machine goes on on another
    with Recorder(where / net.name, meta, ("mcap",), overwrite=True) as rec:
        def record(row, state):
            log_epoch(rec, row)
            save_state(saved, state, fingerprint)

        def resume(template):  # a run stopped midway goes on from its last epoch, recorded again
            state = load_state(saved, template, fingerprint)
            for row in state.history if state is not None else ():
                log_epoch(rec, row)
            return state

        model, history = train(model_cfg, cfg, data, val, spec, progress=False, on_epoch=record, resume=resume)
        inference = inference_times_ms(model, points, budget.timing.repeats, seed)
        mppi = mppi_step_ms(model, points, budget, seed)
        for i, (a, b) in enumerate(zip(inference, mppi)):
            step = budget.networks.epochs + 1 + i
            rec.log_step(step, float(step), metrics={"inference_ms": a, "mppi_step_ms": b})
        save_model(where / net.name, model.params, model_cfg, spec,
                   {"metrics": {k: v for k, v in history[-1].items() if k != "epoch"}}, model.domain)
        rec.finish({"outcome": "success", "steps": len(history)})
    saved.unlink()


def run_networks(table: str, out: Path, budget: Budget, seed: int, command: str) -> int:
    """Train every network of ``table`` not yet recorded; 0."""
    from tqdm import tqdm

    from ncedf import evaluate
    from ncedf.data import DatasetConfig, ValidationConfig, load_dataset
    from ncedf.robot import RobotSpec
    from scenarios.sweep import read_complete

    where = folder(out, table, budget)
    todo = [n for n in networks(table, budget) if read_complete(where / n.name, ("mcap",)) is None]
    nets = budget.networks
    data_cfg = DatasetConfig(n_configs=nets.configs, grid=nets.grid, n_surface=nets.surface, seed=seed)
    val_cfg = ValidationConfig(n_configs=nets.val_configs, n_points=nets.val_points, n_surface=nets.val_surface)
    write_manifest(where, table, budget, command, {"dataset": dataclasses.asdict(data_cfg),
                                                   "validation": dataclasses.asdict(val_cfg), "seed": seed})
    print(f"{table}: {len(networks(table, budget))} networks in {where}, {len(todo)} to train", file=sys.stderr)
    if not todo:
        return 0
    spec = RobotSpec(n_links=1)
    data, val = load_dataset(data_cfg, spec), load_dataset(val_cfg, spec)
    points = timing_points(evaluate.INFERENCE_POINTS, seed)
    for net in tqdm(todo, desc=table, unit="network", file=sys.stderr, dynamic_ncols=True):
        train_network(net, where, budget, data, val, points, seed)
    return 0


# ---------------------------------------------------------------- Tables III and IV: sweeps
def sweep_episodes(table: str, budget: Budget):
    """Every episode of Table III or IV or of the worlds."""
    from ncedf.presets import PRESETS
    from scenarios.sweep import sweep_settings

    controllers = tuple(PRESETS)

    common = {k: v for k, v in (("samples", budget.episodes.samples), ("horizon", budget.episodes.horizon),
                                ("max_steps", budget.episodes.max_steps)) if v is not None}
    if table == "table3":
        small = [s for s in TABLE3_SHAPES if s != "pointcloud:5000"]
        return (sweep_settings(["spheres"], [4], small, controllers, budget.episodes.envs, 1, **common)
                + sweep_settings(["spheres"], [4], ["pointcloud:5000"], controllers, budget.episodes.envs_5000, 1,
                                 **common))
    if table == "worlds":
        from scenarios import WORLDS

        return sweep_settings(list(WORLDS), list(TABLE4_LINKS), ["ncedf"], WORLD_CONTROLLERS,
                              budget.episodes.env_seeds, 1, **common)
    return sweep_settings(["cluttered"], list(TABLE4_LINKS), ["ncedf"], controllers, budget.episodes.env_seeds,
                          budget.episodes.seeds, **common)


def run_episodes(table: str, out: Path, budget: Budget, seed: int, command: str, executor: str = "local",
                 address: str | None = None) -> int:
    """Run the sweep of ``table`` (resumes) on ``executor`` (``local`` or ``ray``, at ``address``); the
    sweep's exit status."""
    from ncedf.presets import PRESETS
    from scenarios.sweep import run_sweep, summary_table

    controllers = WORLD_CONTROLLERS if table == "worlds" else tuple(PRESETS)
    where = folder(out, table, budget)
    episodes = sweep_episodes(table, budget)
    write_manifest(where, table, budget, command, {"controllers": list(controllers), "episodes": len(episodes)})
    report = run_sweep(episodes, where, executor=executor, workers=budget.episodes.workers, address=address)
    if report.signum is not None:
        return report.exit_status
    print(summary_table(report), file=sys.stderr)
    if table == "table3" and report.exit_status == 0:
        from scenarios.floor import run_floor

        return run_floor(where)
    return report.exit_status


# ---------------------------------------------------------------- MPPI step time per representation
def timing_cases(budget: Budget) -> list[tuple[str, int, int]]:
    """(shape, links, points): link counts at ``ncedf.evaluate.INFERENCE_POINTS`` points, point counts at
    TIMING_LINKS links."""
    from ncedf.evaluate import INFERENCE_POINTS

    cases = [(s, l, INFERENCE_POINTS) for s in budget.timing.shapes for l in budget.timing.links]
    cases += [(s, TIMING_LINKS, p) for s in budget.timing.shapes for p in budget.timing.points]
    return list(dict.fromkeys(cases))


def run_timing(out: Path, budget: Budget, seed: int, command: str) -> int:
    """Time MPPI steps per representation against links and obstacle points; one recording per case."""
    import re

    from tqdm import tqdm

    from ncedf.model import load_model
    from recorder import Recorder
    from scenarios.sweep import read_complete

    where = folder(out, "timing", budget)
    write_manifest(where, "timing", budget, command, {"cases": len(timing_cases(budget))})
    name = {c: f"timing_{re.sub(r'[^A-Za-z0-9]+', '-', c[0])}_L{c[1]}_P{c[2]}" for c in timing_cases(budget)}
    todo = [c for c in timing_cases(budget) if read_complete(where / name[c], ("mcap",)) is None]
    print(f"timing: {len(name)} cases in {where}, {len(todo)} to run", file=sys.stderr)
    model = load_model() if todo else None
    for case in tqdm(todo, desc="timing", unit="case", file=sys.stderr, dynamic_ncols=True):
        shape, links, n_points = case
        points = timing_points(n_points, seed)
        meta = {"run_id": f"{where.name}/{name[case]}", "scenario": "timing", "quick": budget.quick, "shape": shape,
                "links": links, "observed_points": n_points, "controller": "paper",
                "mppi": {"samples": budget.timing.samples, "horizon": budget.timing.horizon},
                "model": "shipped default"}
        with Recorder(where / name[case], meta, ("mcap",), overwrite=True) as rec:
            for i, ms in enumerate(mppi_step_ms(model, points, budget, seed, shape, links)):
                rec.log_step(i, float(i), metrics={"solver_ms": ms})
            rec.finish({"outcome": "success", "steps": budget.timing.repeats})
    return 0


def run_table(table: str, out: Path, budget: Budget, seed: int, command: str, executor: str = "local",
              address: str | None = None) -> int:
    if table in ("table1", "table2"):
        return run_networks(table, out, budget, seed, command)
    if table == "timing":
        return run_timing(out, budget, seed, command)
    return run_episodes(table, out, budget, seed, command, executor, address)


# ---------------------------------------------------------------- CLI
def parse_args(argv=None):
    from recorder.cli import OneLineParser, path_text, positive

    p = OneLineParser(prog="python -m scenarios.reproduce", description=__doc__.split("\n\n")[0],
                      epilog="Exit status: 0 done, 1 some episodes failed, 2 bad arguments, 130/143 interrupted "
                             "(run the same command again to finish).")
    p.add_argument("table", choices=(*TABLES, "all"), help="which experiment")
    p.add_argument("--out", type=path_text, default="runs", help="folder of the recordings (default runs/)")
    p.add_argument("--quick", action="store_true",
                   help="a smoke-sized version of every experiment (a fraction of the time)")
    p.add_argument("--epochs", type=positive, help=f"training epochs per network (default {PAPER_EPOCHS}, quick 1)")
    p.add_argument("--envs", type=positive,
                   help=f"Table III environments per representation (default {EpisodeBudget.envs})")
    p.add_argument("--envs-5000", type=positive, metavar="N",
                   help=f"Table III environments for pointcloud:5000 (default {EpisodeBudget.envs_5000})")
    p.add_argument("--seeds", type=positive, help=f"Table IV controller seeds (default {EpisodeBudget.seeds})")
    p.add_argument("--env-seeds", type=positive, metavar="N",
                   help=f"environment seeds of Table IV and the worlds (default {EpisodeBudget.env_seeds})")
    p.add_argument("--timing-repeats", type=positive, metavar="N",
                   help=f"timed steps per network or timing case (default {TimingBudget.repeats}, "
                        f"quick {QUICK.timing.repeats})")
    p.add_argument("--workers", type=positive, help="sweep worker processes (default: one per core)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", metavar="E",
                   help="run the sweeps in local processes or on Ray: local, ray (default local)")
    p.add_argument("--address", help="Ray cluster address (default: RAY_ADDRESS, or a local Ray)")
    p.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    return p.parse_args(argv)


#: The command-line options that override a budget: option -> (part of the budget, its field).
OVERRIDES = {"epochs": ("networks", "epochs"), "envs": ("episodes", "envs"), "envs_5000": ("episodes", "envs_5000"),
             "seeds": ("episodes", "seeds"), "env_seeds": ("episodes", "env_seeds"), "workers": ("episodes", "workers"),
             "timing_repeats": ("timing", "repeats")}


def budget_from(args) -> Budget:
    """The budget of the parsed options: the quick or full one, with the options given."""
    budget = QUICK if args.quick else Budget()
    for option, (part, field) in OVERRIDES.items():
        value = getattr(args, option)
        if value is None:
            continue
        budget = dataclasses.replace(budget, **{part: dataclasses.replace(getattr(budget, part), **{field: value})})
    return budget


def main(argv=None) -> int:
    from recorder import RecorderError, RecordingInterrupted
    from recorder.cli import EXIT_STATUS, Stopped, stop_on_signals
    from recorder.recorder import check_creatable

    args = parse_args(argv)
    budget = budget_from(args)
    out = Path(args.out)
    try:
        check_creatable(out, "recordings")
    except RecorderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.executor == "ray":
        from scenarios.sweep import ray_missing

        if why := ray_missing():
            print(f"error: {why}", file=sys.stderr)
            return 2
    command = "python -m scenarios.reproduce " + " ".join(sys.argv[1:] if argv is None else argv)

    status = 0
    try:
        with stop_on_signals():
            for table in TABLES if args.table == "all" else (args.table,):
                start = time.perf_counter()
                code = run_table(table, out, budget, args.seed, command, args.executor, args.address)
                print(f"{table}: done in {time.perf_counter() - start:.0f} s (exit {code})", file=sys.stderr)
                if code in EXIT_STATUS.values():
                    print(f"interrupted: complete recordings under {out} are kept; run the same command to finish",
                          file=sys.stderr)
                    return code
                status = max(status, code)
    except Stopped as exc:
        print(f"stopped by {exc}: complete recordings under {out} are kept; run the same command to finish",
              file=sys.stderr)
        return EXIT_STATUS[exc.signum]
    except RecordingInterrupted as exc:  # a signal while a network was recorded: it is marked interrupted
        signum = signal.Signals(exc.signum)
        print(f"stopped by {signum.name}: the network in training is recorded as interrupted, complete "
              f"recordings under {out} are kept; run the same command to finish", file=sys.stderr)
        return EXIT_STATUS[signum]
    return status


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
