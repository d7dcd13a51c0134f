"""A folder of recordings read once (through ``recorder.read``) and sorted into experiments.

Every table and figure starts from :func:`load`: the per-run table of
``recorder.read.load_summaries`` (outcome, metadata and per-metric count / mean / std / min / max /
last value), with the unreadable, unclosed and unfinished recordings listed in ``problems`` and left
out. A closed .mcap is read from its footer and summary section only, not its chunks
(``python analysis/bench_read.py`` times both); recordings without the summary record (.rrd,
unclosed, written before it existed) still cost a full read. A figure that
draws a run's steps reads that run with ``recorder.load_run``. :func:`pooled` gives the mean and
std over every step of many runs, exactly, from their per-run statistics.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path

import pandas as pd

from analysis.stats import pooled_mean_std
from ncedf.robot import RobotSpec
from recorder import RecorderError, load_summaries, schema

#: Outcomes of finished runs (anything else, e.g. interrupted or none, is left out).
FINAL = ("success", "collision", "stuck")
#: The paper's link, against which :func:`robot_label` names another robot.
PAPER_ROBOT = RobotSpec(1)


@dataclasses.dataclass(frozen=True)
class Recordings:
    """What a folder holds.

    runs: one row per usable run (recorder.read.load_summaries columns plus ``folder``, ``quick``,
      ``goal_kind``: the settings' goal, ``fixed``, ``random`` or a position ``X,Y,Z``; ``fixed`` where
      they name none; and ``robot``, :func:`robot_label`);
    manifests: one row per experiment manifest;
    problems: (path, why) of every recording left out; seconds: time to read the folder;
    files: recordings found.
    """

    runs: pd.DataFrame
    manifests: pd.DataFrame
    problems: list[tuple[str, str]]
    seconds: float
    files: int

    def scenario(self, name: str) -> pd.DataFrame:
        """Runs of one scenario (``training`` for networks, ``spheres``, ``cluttered`` ...)."""
        if "scenario" not in self.runs:
            return self.runs.iloc[:0]
        return self.runs[self.runs["scenario"] == name]


def _read(folder: Path) -> tuple[pd.DataFrame, list[tuple[str, str]]]:
    """load_summaries(folder) and the files it skipped (path, why)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        runs = load_summaries(folder, kind="all")
    problems = [(str(w.message).removeprefix("skipped: ").split(" ", 1)[0], str(w.message).removeprefix("skipped: "))
                for w in caught if str(w.message).startswith("skipped: ")]
    return runs, problems


def load(folder: str | Path) -> Recordings:
    """Read every recording under ``folder``; raises RecorderError when it is not a folder."""
    folder = Path(folder)
    start = time.perf_counter()
    runs, problems = _read(folder)
    seconds = time.perf_counter() - start
    files = len(runs) + len(problems)
    if runs.empty:
        return Recordings(runs, runs, problems, seconds, files)
    runs = runs.copy()
    runs["folder"] = [str(Path(p).parent) for p in runs["path"]]
    bad = ~runs["complete"].astype(bool) | ~runs["outcome"].isin(FINAL)
    for _, row in runs[bad].iterrows():
        why = "not closed (run killed?)" if not row["complete"] else f"outcome {row['outcome']!r}, not final"
        problems.append((row["path"], why))
    runs = runs[~bad]
    is_manifest = runs["scenario"] == schema.MANIFEST if "scenario" in runs else pd.Series(False, index=runs.index)
    manifests = runs[is_manifest].reset_index(drop=True)
    runs = runs[~is_manifest].reset_index(drop=True)
    quick_folders = set(manifests.loc[manifests["quick"].astype(bool), "folder"]) if "quick" in manifests else set()
    marked = runs["quick"].fillna(False).astype(bool) if "quick" in runs else False
    runs["quick"] = runs["folder"].isin(quick_folders) | marked
    runs["goal_kind"] = runs["settings.goal"].fillna("fixed") if "settings.goal" in runs else "fixed"
    runs["robot"] = [robot_label(row) for _, row in runs.iterrows()]
    return Recordings(runs, manifests, problems, seconds, files)


def sphere_episodes(rec: Recordings) -> pd.DataFrame:
    """The dynamic-sphere episodes of the paper's links (any number of them, the scene as built): those
    whose environments, per link count, Table III's floor columns and ``scenarios.floor`` judge."""
    runs = rec.scenario("spheres")
    return runs[runs["robot"] == ""] if not runs.empty else runs


def robot_label(run: pd.Series) -> str:
    """The robot and the scene's scale of a run, "" for the paper's robot in the scene as built,
    else e.g. "L 0.1 m, r 0.01 m, scale 0.05" (each part only where it differs; a tapered robot's
    radii as "r 0.25-0.15 m")."""
    parts = []
    for name, paper_value in (("length", PAPER_ROBOT.length), ("radius", PAPER_ROBOT.radius)):
        value = run.get(f"robot.{name}")
        label = "L" if name == "length" else "r"
        if isinstance(value, list) and value:
            parts.append(f"{label} {value[0]:g}-{value[-1]:g} m")
        elif isinstance(value, float) and value == value and value != paper_value:
            parts.append(f"{label} {value:g} m")
    options = run.get("settings.options")
    scale = dict(map(tuple, options)).get("scale") if isinstance(options, list) else None
    if scale is not None and float(scale) != 1.0:
        parts.append(f"scale {float(scale):g}")
    return ", ".join(parts)


def pooled(runs: pd.DataFrame, metric: str) -> tuple[float, float, int]:
    """Mean, population std and count of ``metric`` over every step of ``runs`` (finite values only),
    pooled from their per-run statistics; NaNs and 0 when no run has a value."""
    if f"{metric}.count" not in runs:
        return pooled_mean_std([], [], [])
    return pooled_mean_std(runs[f"{metric}.count"], runs[f"{metric}.mean"], runs[f"{metric}.std"])


#: What :func:`machine_name` reads for a run whose metadata names no machine.
NOT_RECORDED = "not recorded"


def machine_name(run: pd.Series) -> str:
    """The machine a run's or manifest's metadata names, "cpu, N cores, device" (``NOT_RECORDED``
    where it names none: recordings made before runs named theirs)."""
    if pd.isna(run.get("machine.cpu", float("nan"))):
        return NOT_RECORDED
    return f"{run['machine.cpu']}, {int(run['machine.cores'])} cores, {run['machine.device']}"


def hardware(rec: Recordings, folders) -> str:
    """The machines named by the manifests of ``folders`` (or "unknown machine")."""
    if rec.manifests.empty or "machine.cpu" not in rec.manifests:
        return "unknown machine (no experiment manifest)"
    m = rec.manifests[rec.manifests["folder"].isin(set(folders))]
    names = sorted({machine_name(r) for _, r in m.iterrows()})
    return "; ".join(names) or "unknown machine (no experiment manifest)"


#: The folder the analysis reads by default, where it exists (the sweep's and reproduction's).
DEFAULT_RUNS = "runs"


def recordings_folder(folder: str | Path | None) -> Path:
    """The folder to read: ``folder``, or by default ``runs/`` where it exists and else the
    current folder (where a runner writes ``recording.rrd`` / ``.mcap``). RecorderError with a
    one-line message when it is not a folder."""
    if folder is None:
        folder = DEFAULT_RUNS if Path(DEFAULT_RUNS).is_dir() else "."
    if not Path(folder).is_dir():
        raise RecorderError(f"{folder} is not a folder of recordings")
    return Path(folder)
