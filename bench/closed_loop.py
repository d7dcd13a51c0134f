"""Closed-loop ablation of the controller, judged exactly: ``python bench/closed_loop.py``.

    python bench/closed_loop.py --quick
    python bench/closed_loop.py --links 4,5,7 --seeds 5 --envs 20 --variants release,ours,paper
    python bench/closed_loop.py --variants ours,ours-route --scenarios cluttered --seeds 20
    python bench/closed_loop.py --variants ours,ours:temperature.target=0.05:sampling.smoothing=0.5 --links 4

A variant is a preset of ``ncedf.presets`` with some stages changed
(``VARIANTS``): ``ours`` with one of its stages or options turned off
(``ours-X``) or a candidate it leaves out turned on (``ours+X``), ``release``
with ours's sampling, and ``paper`` at ``ours``'s rollouts and horizon (the
reference of the solver time). ``PRESET:STAGE.FIELD=VALUE[:...]`` changes a
field of a stage (values: numbers, true, false, none or text) and
``PRESET:STAGE=none`` removes a stage. A change to a stage that the preset
does not use in a world (``ours`` among the balls has no obstacle model) is
refused for that world.

Every variant runs the same episodes (``scenarios.episode``, no recording): the
cluttered scene for each of ``--links`` x ``--seeds`` controller seeds, and the
dynamic spheres for ``--envs`` environments x ``--goals`` (controller seed
``--seed0``), 4 links, and each world of ``scenarios.WORLDS`` named in
``--scenarios`` for ``--links`` x ``--envs`` environments. Printed per variant and group: episodes, success /
collision / stuck counts with 95% Wilson intervals, the median reach step of
the successes, the solver time per step (mean +- std over all its steps) and
its ratio to ``paper``'s in the same run.

``--timing STEPS`` measures the solver time alone: for each group, every
variant plans from the scene's start STEPS times against the cloud at the
step's time, the variants in turn so that all see the same load
(``solver_time.solver_times``); printed: median and mean +- std ms per step and
the ratio of each median to ``paper``'s.

Results: ``docs/experiments.md``; the history of the experiments:
``docs/controller-experiments.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import textwrap
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.stats import wilson
from ncedf.controller import Controller
from ncedf.presets import PRESETS, Observation
from ncedf.temperature import Fixed
from recorder.cli import EXIT_STATUS, OneLineParser, Stopped, exit_with, stop_on_signals
from scenarios import WORLDS
from scenarios.episode import Episode, EpisodeSettings, build_scene

from arguments import non_negative, output_file, parse_list, positive, positive_float
from solver_time import solver_times

#: name -> (preset, changes: "stage.field" or "stage" -> value). ``paper`` also takes ``ours``'s sizes.
VARIANTS: dict[str, tuple[str, dict]] = {
    "release": ("release", {}),
    "release+sampling": ("release", {"sampling.kind": "release"}),
    "ours": ("ours", {}),
    "ours-sampling": ("ours", {"sampling.kind": "project"}),
    "ours-ess": ("ours", {"temperature": Fixed()}),
    "ours-check": ("ours", {"safety": None}),  # the whole filter: among the balls its sweep and warm start too
    "ours+smooth": ("ours", {"sampling.smoothing": 0.6}),
    "ours-smooth": ("ours", {"sampling.smoothing": 0.0}),
    "ours-sweep": ("ours", {"safety.sweep_first": False}),
    "ours-stall": ("ours", {"temperature.escape": None}),
    "ours-unclipped": ("ours", {"sampling.unclipped": False}),
    "ours-reach": ("ours", {"mppi.goal_reach": False}),
    "ours+race": ("ours", {"sampling.unclipped": True, "mppi.goal_reach": True}),
    "ours-convex": ("ours", {"model": None, "recovery": None}),  # the route plans round the model
    "ours-weights": ("ours", {"mppi.w_coll": 1.1, "mppi.w_coll_terminal": 1.1}),
    "ours-follow": ("ours", {"safety.follow_executed": False}),
    "ours-route": ("ours", {"recovery": None}),
    "ours-grid": ("ours", {"model": None, "guide": None, "recovery": None}),  # the points alone
    "ours-guide": ("ours", {"guide": None}),
    "paper": ("paper", {}),
}
QUICK = {"links": "4,5,7", "seeds": 1, "envs": 2, "variants": "ours,paper", "max_steps": 60}


def parse_value(text: str):
    """A field value from the command line: none, true, false, an int, a float, or the text."""
    lowered = text.lower()
    if lowered in ("none", "true", "false"):
        return {"none": None, "true": True, "false": False}[lowered]
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def resolve(variant: str) -> tuple[str, dict]:
    """(preset, changes) of a named variant or of ``PRESET:STAGE.FIELD=VALUE:...``."""
    if variant in VARIANTS:
        return VARIANTS[variant]
    preset, *pairs = variant.split(":")
    if preset not in PRESETS or not pairs or any("=" not in pair for pair in pairs):
        raise ValueError(f"unknown variant {variant!r}; choose from {', '.join(VARIANTS)} "
                         "or PRESET:STAGE.FIELD=VALUE[:...]")
    return preset, {name: parse_value(value) for name, value in (pair.split("=", 1) for pair in pairs)}


def changed(config, changes: dict):
    """``config`` (a ControllerConfig) with the changes applied, the stages replaced whole first (at
    once: ``model`` and ``recovery`` go together); ValueError names a bad one."""
    whole = {path: value for path, value in changes.items() if "." not in path}
    unknown = [stage for stage in whole if not hasattr(config, stage)]
    if unknown:
        raise ValueError(f"no stage {unknown[0]!r}")
    config = dataclasses.replace(config, **whole)
    for path, value in changes.items():
        if path in whole:
            continue
        stage, _, field = path.partition(".")
        part = getattr(config, stage, None)
        if part is None or field not in {f.name for f in dataclasses.fields(part)}:
            raise ValueError(f"no field {path!r} here (the stage is {part!r})")
        config = dataclasses.replace(config, **{stage: dataclasses.replace(part, **{field: value})})
    return config


def episodes(args) -> list[tuple[str, EpisodeSettings]]:
    """(group, settings) of every episode a variant runs (controller filled in per variant)."""
    out = []
    shared = (("scale", str(args.scale)),) if args.scale else ()
    options = (("density", str(args.density)),) + shared if args.density else shared
    model = str(args.model.resolve()) if args.model else None
    if "cluttered" in args.scenarios:
        for links in args.links:
            for seed in range(args.seed0, args.seed0 + args.seeds):
                out.append((f"cluttered L{links}", EpisodeSettings("cluttered", links, seed, model=model,
                                                                   max_steps=args.max_steps, options=options)))
    if "spheres" in args.scenarios:
        for goal in args.goals:
            for env in range(args.env0, args.env0 + args.envs):
                out.append((f"spheres {goal}", EpisodeSettings("spheres", 4, args.seed0, env_seed=env, goal=goal,
                                                               model=model, max_steps=args.max_steps,
                                                               options=shared)))
    for world in (w for w in WORLDS if w in args.scenarios):
        for links in args.links:
            for env in range(args.env0, args.env0 + args.envs):
                out.append((f"{world} L{links}", EpisodeSettings(world, links, args.seed0, env_seed=env,
                                                                 model=model, max_steps=args.max_steps,
                                                                 options=shared)))
    return out


def make_episode(variant: str, settings: EpisodeSettings) -> Episode:
    """The prepared episode of ``variant`` (``paper`` at ours's rollouts and horizon)."""
    preset, changes = resolve(variant)
    episode = Episode(dataclasses.replace(settings, controller=preset))
    scene = episode.scene
    config = changed(scene.config, changes)
    if preset == "paper":
        ours = PRESETS["ours"](scene.spec, Observation(scene.observer.n_points, scene.world.margin_extra)).mppi
        config = dataclasses.replace(config, mppi=dataclasses.replace(config.mppi, samples=ours.samples,
                                                                      horizon=ours.horizon))
    if config != scene.config:
        episode.scene = dataclasses.replace(scene, config=config)
        episode.mppi = Controller(scene.spec, episode.shape, config)
    return episode


def run_one(variant: str, settings: EpisodeSettings):
    """One episode of ``variant`` (no recording): its EpisodeResult."""
    return make_episode(variant, settings).run(out=None)


def timing_table(args) -> str:
    """``--timing``: one line per group and variant (see the module docstring)."""
    lines = [f"{'group':<16}{'variant':<18}{'N':>6}{'H':>4}{'median ms':>11}{'mean +- std ms':>19}{'/paper':>8}"]
    seen = set()
    for group, settings in episodes(args):
        if group in seen:
            continue
        seen.add(group)
        prepared = {v: make_episode(v, settings) for v in args.variants}
        t = solver_times(prepared, args.timing)
        paper_median = np.median(t["paper"]) if "paper" in t else None
        for v, episode in prepared.items():
            med = np.median(t[v])
            ratio = f"{med / paper_median:>8.2f}" if paper_median else f"{'-':>8}"
            core = episode.scene.config.mppi
            lines.append(f"{group:<16}{v:<18}{core.samples:>6}{core.horizon:>4}"
                         f"{med:>11.1f}{t[v].mean():>11.1f} +- {t[v].std():<5.1f}{ratio}")
    return "\n".join(lines)


def summarise(rows: list[dict]) -> str:
    """The table of results (see the module docstring)."""
    groups = defaultdict(list)
    for row in rows:
        groups[(row["group"], row["variant"])].append(row)
    paper_ms = {g: np.mean([r["ms_mean"] for r in rs]) for (g, v), rs in groups.items() if v == "paper"}
    lines = [f"{'group':<16}{'variant':<18}{'n':>4}  {'success [95% CI]':<22}{'collision [95% CI]':<22}"
             f"{'stuck':>6}{'reach med':>10}{'solver ms':>18}{'/paper':>8}"]
    for (group, variant), rs in sorted(groups.items()):
        n = len(rs)
        counts = {o: sum(r["outcome"] == o for r in rs) for o in ("success", "collision", "stuck")}
        cell = {o: "{:>2} ({:.2f}-{:.2f})".format(counts[o], *wilson(counts[o], n)) for o in counts}
        reach = [r["reach_step"] for r in rs if r["reach_step"] is not None]
        med = f"{np.median(reach):.0f}" if reach else "-"
        means = np.array([r["ms_mean"] for r in rs])
        weights = np.array([r["steps"] for r in rs], float)
        mean = float(np.average(means, weights=weights))
        var = float(np.average(np.array([r["ms_std"] for r in rs]) ** 2 + (means - mean) ** 2, weights=weights))
        ratio = f"{np.mean(means) / paper_ms[group]:.2f}" if group in paper_ms else "-"
        lines.append(f"{group:<16}{variant:<18}{n:>4}  {cell['success']:<22}{cell['collision']:<22}"
                     f"{counts['stuck']:>6}{med:>10}{mean:>10.1f} +- {math.sqrt(var):<5.1f}{ratio:>8}")
    return "\n".join(lines)


def parse_variants(text: str) -> list[str]:
    values = parse_list(text, str, "variant")
    for value in values:
        try:
            resolve(value)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return values


def episodes_config_check(variant: str, settings: EpisodeSettings) -> None:
    """Raise ValueError naming a change that the variant's preset cannot take in this world."""
    preset, changes = resolve(variant)
    try:
        changed(build_scene(dataclasses.replace(settings, controller=preset)).config, changes)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"variant {variant!r} in the {settings.scenario} scene: {exc}") from None


def main(argv=None) -> int:
    listed = textwrap.fill(", ".join(VARIANTS), width=98, initial_indent="  ", subsequent_indent="  ")
    epilog = f"{__doc__}\nVARIANTS:\n{listed}\nworlds: {', '.join(WORLDS)}\n"
    p = OneLineParser(description=__doc__.split("\n\n")[0], epilog=epilog,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", default="release,ours,paper", metavar="LIST",
                   type=parse_variants,
                   help="VARIANTS below or PRESET:STAGE.FIELD=VALUE[:...], comma-separated "
                        "(default release,ours,paper)")
    p.add_argument("--scenarios", default="cluttered,spheres", metavar="LIST",
                   type=lambda t: parse_list(t, str, "scenario", ("cluttered", "spheres") + WORLDS),
                   help="comma-separated: cluttered, spheres or worlds (below); default cluttered,spheres")
    p.add_argument("--links", default="4,5,7", type=lambda t: parse_list(t, int, "links", above_zero=True),
                   help="cluttered link counts (default 4,5,7)")
    p.add_argument("--seeds", type=positive, default=3, help="cluttered controller seeds per link count (default 3)")
    p.add_argument("--seed0", type=non_negative, default=0,
                   help="first controller seed; the spheres' episodes use this one (default 0)")
    p.add_argument("--density", type=positive_float,
                   help="cluttered: observed points per m^2 of box face (default: the paper's 4)")
    p.add_argument("--envs", type=positive, default=10,
                   help="spheres environments per goal kind, and each world's per link count (default 10)")
    p.add_argument("--env0", type=non_negative, default=0, help="first spheres or world environment (default 0)")
    p.add_argument("--goals", default="fixed", type=lambda t: parse_list(t, str, "goal", ("fixed", "random")),
                   help="spheres goal kinds (default fixed)")
    p.add_argument("--max-steps", type=positive, help="override every scenario's step budget")
    p.add_argument("--model", type=Path, help="N-CEDF weights: the robot and its network (default: the shipped)")
    p.add_argument("--scale", type=positive_float, help="scale every scene by S about the base (default 1)")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 1 seed, 2 environments, ours and paper, 60 steps")
    p.add_argument("--timing", type=positive, metavar="STEPS",
                   help="instead of episodes: solver ms of each variant and its ratio to paper, STEPS steps per group")
    p.add_argument("--json", type=output_file, help="also write every episode's result here")
    args = p.parse_args(argv)
    if args.quick:
        args.links, args.seeds, args.envs = [4, 5, 7], QUICK["seeds"], QUICK["envs"]
        args.variants, args.max_steps = QUICK["variants"].split(","), QUICK["max_steps"]
    firsts = {group: settings for group, settings in reversed(episodes(args))}
    for variant in args.variants:
        for settings in firsts.values():
            try:
                episodes_config_check(variant, settings)
            except ValueError as exc:
                p.error(str(exc))
    if "paper" not in args.variants:
        print("note: without the paper variant there is no solver-time ratio", file=sys.stderr)

    if args.timing:
        try:
            with stop_on_signals():
                print(timing_table(args))
        except Stopped as stop:
            print(f"interrupted ({stop}): no timing table", file=sys.stderr)
            return EXIT_STATUS[stop.signum]
        return 0
    rows = []
    todo = [(v, g, s) for v in args.variants for g, s in episodes(args)]
    start = time.perf_counter()
    try:
        with stop_on_signals():
            for variant, group, settings in tqdm(todo, desc="episodes", file=sys.stderr, dynamic_ncols=True):
                r = run_one(variant, settings)
                rows.append({"variant": variant, "group": group, "links": settings.links, "seed": settings.seed,
                             "env_seed": settings.env_seed, "outcome": r.outcome, "reach_step": r.reach_step,
                             "steps": r.steps, "min_true_distance": r.min_true_distance,
                             "final_goal_distance": r.final_goal_distance, "ms_mean": r.solver_ms_mean,
                             "ms_std": r.solver_ms_std})
    except Stopped as stop:
        print(f"interrupted ({stop}): {len(rows)} of {len(todo)} episodes finished; their table follows",
              file=sys.stderr)
        if rows:
            print(summarise(rows))
        return EXIT_STATUS[stop.signum]
    print(summarise(rows))
    print(f"{len(rows)} episodes in {time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    exit_with(main())
