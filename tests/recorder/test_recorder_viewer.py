"""`Recorder(viewer=...)`: where the live stream goes, what it carries, and that the files do not change.

The live end is `rerun --serve-grpc --save FILE` (the gRPC proxy a viewer connects to), which writes
what it receives: the test compares that with the recording's own .rrd.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pandas as pd
import pytest
from recorder_readback import rrd_values

from recorder import Recorder, ViewerWarning, load_run, viewer
from recorder.synthetic import SyntheticRun
from recorder.synthetic import main as synthetic_main

RERUN = str(Path(sys.executable).with_name("rerun"))
STEPS = 3


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def record(out: Path, viewer_arg=False) -> bool:
    """Record a short run; whether it was streamed live."""
    run = SyntheticRun(links=2, seed=1, rings=3, ring_points=4, n_points=6, horizon=3, pose_goal=True)
    with Recorder(out, run.meta, safety_margin=run.safety_margin, goal_tolerance=run.goal_tolerance,
                  viewer=viewer_arg) as rec:
        for k in range(STEPS):
            rec.log_step(k, 0.1 * k, **run.step(k))
            rec.log_text(f"step {k}")
        live = rec.live
        rec.finish({"outcome": "success", "steps": STEPS})
    return live


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    """The same run recorded without a viewer."""
    out = tmp_path_factory.mktemp("plain") / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no viewer asked: no warning
        assert not record(out)
    return out


@pytest.fixture
def proxy(tmp_path):
    """A `rerun --serve-grpc` proxy on a free port, saving what it receives: (url, saved path, process)."""
    saved = tmp_path / "live.rrd"
    port = free_port()
    proc = subprocess.Popen([RERUN, "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port), "--save", str(saved)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "RERUN_ANALYTICS": "0"},
                            # SIGINT stops it (teardown), even if this process has it ignored or handled.
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 20
    while not viewer.listening("127.0.0.1", port, timeout=0.2):
        assert proc.poll() is None and time.monotonic() < deadline, "rerun --serve-grpc did not start"
        time.sleep(0.05)
    yield viewer.local_url(port), saved, proc
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)


def assert_same_rrd(a: Path, b: Path) -> None:
    res = subprocess.run([RERUN, "rrd", "compare", "--unordered", str(a), str(b)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]


def test_live_stream_carries_the_recording_and_the_file_is_unchanged(plain, proxy, tmp_path):
    url, saved, proc = proxy
    out = tmp_path / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert record(out, url)
    assert_same_rrd(out.with_suffix(".rrd"), plain.with_suffix(".rrd"))
    assert out.with_suffix(".mcap").read_bytes() == plain.with_suffix(".mcap").read_bytes()

    proc.send_signal(signal.SIGINT)  # the proxy writes what it received and exits
    proc.wait(timeout=20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the proxy's file has no footer
        live = rrd_values(saved)
    mine = rrd_values(out.with_suffix(".rrd"))
    assert live == mine  # every component at every step, and the static ones
    assert {"/world/robot/mesh", "/world/goal_marker/approach", "/metrics/goal_distance", "/log"} <= {
        entity for entity, _, _ in mine}
    assert {step for _, _, step in mine} == {None, *range(STEPS)}


def test_unreachable_viewer_warns_once_and_records_the_same_files(plain, tmp_path):
    url = viewer.local_url(free_port())  # nothing listens there
    out = tmp_path / "run"
    with pytest.warns(ViewerWarning) as caught:
        assert not record(out, url)
    assert [str(w.message) for w in caught] == [f"no Rerun viewer listening at {url}; recording to files only"]
    assert caught[0].filename == __file__  # attributed to the caller, not to the recorder
    assert_same_rrd(out.with_suffix(".rrd"), plain.with_suffix(".rrd"))
    a, b = load_run(out.with_suffix(".rrd")), load_run(out.with_suffix(".mcap"))
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    assert a.complete and b.complete and len(a.metrics) == STEPS


def test_viewer_true_connects_to_a_listening_viewer(proxy):
    url, _, proc = proxy
    assert proc.poll() is None
    port = int(url.rsplit(":", 1)[1].split("/")[0])
    assert viewer.resolve(True, port=port) == viewer.ViewerTarget(url)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display check is for Linux")
def test_viewer_true_without_display_or_program_warns(monkeypatch, tmp_path):
    port = free_port()  # nothing listens: a viewer would have to be started
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.warns(ViewerWarning, match=r"^cannot start a Rerun viewer: no display \(DISPLAY and WAYLAND_DISPLAY "
                                           r"are unset\); recording to files only$"):
        assert viewer.resolve(True, port=port) is None
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))  # no `rerun` beside it
    monkeypatch.setenv("PATH", str(tmp_path))  # nor on PATH
    with pytest.warns(ViewerWarning, match="the `rerun` program is not installed"):
        assert viewer.resolve(True, port=port) is None
    monkeypatch.setattr(sys, "executable", str(Path(RERUN).with_name("python")))
    assert viewer.resolve(True, port=port) == viewer.ViewerTarget(viewer.local_url(port), spawn=True,
                                                                   executable=Path(RERUN))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display check is for Linux")
def test_viewer_true_without_display_still_records(monkeypatch, tmp_path):
    """The default port may be taken on a developer's machine: only run this where it is free."""
    if viewer.listening("127.0.0.1", viewer.DEFAULT_PORT):
        pytest.skip(f"a viewer listens on port {viewer.DEFAULT_PORT}")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.warns(ViewerWarning, match="cannot start a Rerun viewer"):
        assert not record(tmp_path / "run", True)
    assert load_run(tmp_path / "run.rrd").complete


@pytest.mark.parametrize("bad", ["http://127.0.0.1:9876/proxy", "rerun+http://127.0.0.1/proxy",
                                 "rerun+http://127.0.0.1:9876/", "yes", 1])
def test_bad_viewer_values_raise(tmp_path, bad):
    with pytest.raises(ValueError, match="viewer .* must be True, False or a URL like"):
        Recorder(tmp_path / "r", {}, viewer=bad)
    assert not (tmp_path / "r.rrd").exists()


def test_cli_rejects_a_bad_viewer_url(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        synthetic_main([str(tmp_path / "r"), "--viewer", "localhost:9876"])
    assert exit_.value.code == 2
    assert "viewer 'localhost:9876' must be True, False or a URL like" in capsys.readouterr().err
