"""A folder of recordings read once (through ``recorder.read``) and sorted into experiments.

Every table and figure starts from :func:`load`: the per-run table and the long per-step table
of ``recorder.read.load_runs``, with the unreadable, unclosed and unfinished recordings listed in
``problems`` and left out of both.

Reading costs 4.6 ms per recording of 21 steps (0.7 MB) and 43 ms per 300-step cluttered
episode (10 MB), mostly zstd (the metrics share chunks with the meshes): 18 s for 4000 short
recordings, about 3 min for 4000 full ones (``python analysis/bench_read.py``, 2 shared cores).
So ``load`` keeps what it read in a per-user cache (``$NCEDF_CACHE/analysis``, a pickle written by
this user) and reuses it while no recording under the folder changed (paths, sizes, modification
times): ``make_tables`` then ``make_figures`` read the recordings once.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import time
import warnings
from pathlib import Path

import pandas as pd

from recorder import RecorderError, load_runs
from recorder.read import find_recordings

#: Outcomes of finished runs (anything else, e.g. interrupted or none, is left out).
FINAL = ("success", "collision", "stuck")
#: Scenario name of an experiment's manifest recording (scenarios.reproduce).
MANIFEST = "experiment"
#: Environment variable of the cache folder (as ncedf.data's dataset cache; default ~/.cache/ncedf).
CACHE_ENV = "NCEDF_CACHE"


@dataclasses.dataclass(frozen=True)
class Recordings:
    """What a folder holds.

    runs: one row per usable run (recorder.read.load_runs columns plus ``folder`` and ``quick``);
    steps: their per-step metrics; manifests: one row per experiment manifest;
    problems: (path, why) of every recording left out; seconds: time to read the folder;
    files: recordings found.
    """

    runs: pd.DataFrame
    steps: pd.DataFrame
    manifests: pd.DataFrame
    problems: list[tuple[str, str]]
    seconds: float
    files: int

    def scenario(self, name: str) -> pd.DataFrame:
        """Runs of one scenario (``training`` for networks, ``spheres``, ``cluttered`` ...)."""
        if "scenario" not in self.runs:
            return self.runs.iloc[:0]
        return self.runs[self.runs["scenario"] == name]


def _signature(folder: Path) -> str:
    """A hash of every recording's path, size and modification time."""
    h = hashlib.sha256()
    for path in find_recordings(folder):
        st = path.stat()
        h.update(f"{path}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _read(folder: Path, cache: bool) -> tuple[pd.DataFrame, pd.DataFrame, list[tuple[str, str]]]:
    """load_runs(folder) and the files it skipped, from the cache when no recording changed."""
    signature = _signature(folder)
    root = Path(os.environ.get(CACHE_ENV, Path.home() / ".cache" / "ncedf")) / "analysis"
    cached = root / (hashlib.sha256(str(folder.resolve()).encode()).hexdigest()[:16] + ".pkl")
    if cache and cached.is_file():
        try:
            with open(cached, "rb") as f:
                saved = pickle.load(f)
            if saved[0] == signature:
                return saved[1:]
        except Exception:  # an unreadable cache is only read again from the recordings
            pass
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        runs, steps = load_runs(folder)
    problems = [(str(w.message).removeprefix("skipped: ").split(" ", 1)[0], str(w.message).removeprefix("skipped: "))
                for w in caught if str(w.message).startswith("skipped: ")]
    if cache:
        try:
            root.mkdir(parents=True, exist_ok=True)
            with open(cached, "wb") as f:
                pickle.dump((signature, runs, steps, problems), f)
        except OSError:  # an unwritable cache folder: no cache
            pass
    return runs, steps, problems


def load(folder: str | Path, cache: bool = True) -> Recordings:
    """Read every recording under ``folder`` (``cache``: reuse the last read while nothing changed);
    raises RecorderError when it is not a folder."""
    folder = Path(folder)
    start = time.perf_counter()
    runs, steps, problems = _read(folder, cache)
    problems = list(problems)
    seconds = time.perf_counter() - start
    files = len(runs) + len(problems)
    if runs.empty:
        return Recordings(runs, steps, runs, problems, seconds, files)
    runs = runs.copy()
    runs["folder"] = [str(Path(p).parent) for p in runs["path"]]
    bad = ~runs["complete"].astype(bool) | ~runs["outcome"].isin(FINAL)
    for _, row in runs[bad].iterrows():
        why = "not closed (run killed?)" if not row["complete"] else f"outcome {row['outcome']!r}, not final"
        problems.append((row["path"], why))
    runs = runs[~bad]
    is_manifest = runs["scenario"] == MANIFEST if "scenario" in runs else pd.Series(False, index=runs.index)
    manifests = runs[is_manifest].reset_index(drop=True)
    runs = runs[~is_manifest].reset_index(drop=True)
    quick_folders = set(manifests.loc[manifests["quick"].astype(bool), "folder"]) if "quick" in manifests else set()
    marked = runs["quick"].fillna(False).astype(bool) if "quick" in runs else False
    runs["quick"] = runs["folder"].isin(quick_folders) | marked
    steps = steps[steps["run_id"].isin(set(runs["run_id"]))]
    return Recordings(runs, steps, manifests, problems, seconds, files)


def hardware(rec: Recordings, folders) -> str:
    """The machines named by the manifests of ``folders`` (or "unknown machine")."""
    if rec.manifests.empty or "machine.cpu" not in rec.manifests:
        return "unknown machine (no experiment manifest)"
    m = rec.manifests[rec.manifests["folder"].isin(set(folders))]
    names = sorted({f"{r['machine.cpu']}, {int(r['machine.cores'])} cores, {r['machine.device']}"
                    for _, r in m.iterrows()})
    return "; ".join(names) or "unknown machine (no experiment manifest)"


def check_folder(folder: str | Path) -> None:
    """RecorderError with a one-line message when ``folder`` is not a folder."""
    if not Path(folder).is_dir():
        raise RecorderError(f"{folder} is not a folder of recordings")
