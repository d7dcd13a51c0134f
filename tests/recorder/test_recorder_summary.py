"""The MCAP `summary` record and `recorder.read.load_summaries`.

The statistics are checked against values computed here from `load_run`'s metrics of the same file
(math.fsum and statistics.pstdev, not the recorder's code), and the three ways of getting them (the
record, the .rrd rows, an .mcap without the record) against each other, exactly.
"""

from __future__ import annotations

import math
import shutil
import statistics

import numpy as np
import pandas as pd
import pytest

from recorder import IncompleteRecordingWarning, Recorder, load_run, load_summaries, mcap_scan, summary
from recorder.synthetic import SyntheticRun

STEPS = 40
OUTCOME = {"outcome": "stuck", "steps": STEPS, "reach_step": None, "min_true_distance": 0.25,
           "first_collision_step": None}


def record(out, seed: int = 0) -> None:
    """A run with meshes (so /metrics shares chunks with them), NaNs, a metric in some rows only, and an
    extra metric that is never finite."""
    run = SyntheticRun(links=3, seed=seed, rings=5, ring_points=8, n_points=50, horizon=4)
    rng = np.random.default_rng(seed)
    with Recorder(out, {**run.meta, "run_id": f"run{seed}", "mppi": {"horizon": 4}}, flush_every=7) as rec:
        for k in range(STEPS):
            kwargs = run.step(k)
            metrics = {**kwargs.pop("metrics"), "solver_ms": float(rng.lognormal(3.0, 0.5)), "never": math.nan}
            if k % 5 == 0:
                metrics["solver_ms"] = math.nan
            if k % 3 == 0:
                metrics["mae"] = float(rng.uniform())
            rec.log_step(k, 0.05 * k, metrics=metrics, **kwargs)
        rec.finish(OUTCOME)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("summary")
    record(root / "both" / "run0")
    return root


def expected(metrics: pd.DataFrame) -> dict[str, float]:
    """The summary columns computed here from a metrics table."""
    out = {summary.ROWS: len(metrics)}
    for name in metrics.columns[2:]:
        finite = metrics[np.isfinite(metrics[name])]
        v = finite[name].tolist()
        out[f"{name}.count"] = len(v)
        if not v:
            out.update({f"{name}.{k}": math.nan for k in summary.STATS[1:]})
            continue
        out.update({f"{name}.mean": math.fsum(v) / len(v), f"{name}.std": statistics.pstdev(v),
                    f"{name}.min": min(v), f"{name}.max": max(v), f"{name}.last": v[-1],
                    f"{name}.last_step": int(finite["step"].iloc[-1])})
    return out


def one(folder) -> pd.Series:
    table = load_summaries(folder)
    assert len(table) == 1
    return table.iloc[0]


def check(row: pd.Series, want: dict[str, float]) -> None:
    for key, value in want.items():
        if isinstance(value, int) or math.isnan(value):
            assert row[key] == value or (math.isnan(value) and math.isnan(row[key])), key
        else:
            assert row[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_record_holds_the_statistics_of_the_metrics(folder, monkeypatch):
    path = folder / "both" / "run0.mcap"
    assert summary.RECORD in mcap_scan.indexed_metadata(path)
    run = load_run(path)

    def no_chunks(*args):
        raise AssertionError("a chunk was opened")

    monkeypatch.setattr(mcap_scan, "_decompress", no_chunks)
    only = folder / "mcap"
    only.mkdir()
    shutil.copy(path, only)
    row = one(only)
    assert (row["run_id"], row["format"], row["complete"], row["mppi.horizon"]) == ("run0", "mcap", True, 4)
    assert {k: row[k] for k in OUTCOME if row[k] is not None} == {k: v for k, v in OUTCOME.items() if v is not None}
    want = expected(run.metrics)
    assert want["solver_ms.count"] == STEPS - STEPS // 5 and want["mae.count"] == (STEPS + 2) // 3
    assert want["never.count"] == 0
    check(row, want)
    assert [c for c in row.index if c.startswith("solver_ms.")] == [f"solver_ms.{k}" for k in summary.STATS]


def test_rrd_and_mcap_without_the_record_give_the_same_values(folder, tmp_path, monkeypatch):
    fast = one(folder / "both")  # the .mcap of the pair, from its record
    rrd = tmp_path / "rrd"
    rrd.mkdir()
    shutil.copy(folder / "both" / "run0.rrd", rrd)
    from_rrd = one(rrd)
    monkeypatch.setattr(summary, "RECORD", "not-the-summary")  # written as before the record existed
    record(tmp_path / "old" / "run0")
    monkeypatch.undo()
    assert summary.RECORD not in mcap_scan.indexed_metadata(tmp_path / "old" / "run0.mcap")
    (tmp_path / "old" / "run0.rrd").unlink()
    from_rows = one(tmp_path / "old")
    assert from_rrd["format"] == "rrd" and from_rows["format"] == "mcap"
    for other in (from_rrd, from_rows):
        pd.testing.assert_series_equal(fast.drop(["path", "format"]), other.drop(["path", "format"]),
                                       check_names=False)


def test_unclosed_and_unreadable_files(folder, tmp_path):
    data = (folder / "both" / "run0.mcap").read_bytes()
    (tmp_path / "killed.mcap").write_bytes(data[: len(data) // 2])
    (tmp_path / "garbage.mcap").write_bytes(b"not a recording")
    with pytest.warns(UserWarning, match="garbage.mcap"):
        row = one(tmp_path)
    assert row["path"].endswith("killed.mcap") and not row["complete"] and row["outcome"] is None
    with pytest.warns(IncompleteRecordingWarning):
        metrics = load_run(tmp_path / "killed.mcap").metrics
    assert 0 < len(metrics) < STEPS
    check(row, expected(metrics))
