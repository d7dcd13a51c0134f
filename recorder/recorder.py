"""`Recorder`: takes typed step events and fans them out to the Rerun and MCAP sinks.

Each sink's module (rerun-sdk, foxglove-sdk) is imported when a recording of its format opens,
so code that imports the recorder but writes only .mcap, or nothing (the benchmarks), runs
where rerun-sdk is missing."""

from __future__ import annotations

import hashlib
import json
import math
import signal
import tempfile
import threading
import uuid
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from recorder import schema, viewer as live_viewer
from recorder.errors import RecorderError, RecordingInterrupted
from recorder.events import make_step

FORMATS = ("rrd", "mcap")
#: Default MCAP mesh interval (steps), chosen with bench/recording_cost.py (docs/experiments.md).
MCAP_MESH_EVERY = 1
_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def output_paths(out: str | Path, formats=FORMATS) -> dict[str, Path]:
    """`out` (a .rrd/.mcap suffix is dropped) -> {format: path}: recording -> recording.rrd, recording.mcap."""
    out = Path(out)
    if out.suffix in (".rrd", ".mcap"):
        out = out.with_suffix("")
    unknown = set(formats) - set(FORMATS)
    if unknown or not formats:
        raise ValueError(f"formats must be a non-empty subset of {FORMATS}, got {formats!r}")
    return {fmt: out.with_name(f"{out.name}.{fmt}") for fmt in FORMATS if fmt in formats}


def check_writable(paths: dict[str, Path], overwrite: bool, what: str = "recordings") -> None:
    """Raise `RecorderError` if an output (one of ``what``) is not a file, exists (and not `overwrite`), or its
    folder cannot be written."""
    for path in paths.values():
        if path.exists() and not path.is_file():
            raise RecorderError(f"{path} is a folder or another non-file; {what} cannot replace it")
        if path.exists() and not overwrite:
            raise RecorderError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
    for folder in {p.parent for p in paths.values()}:
        check_folder(folder, what)


def check_creatable(folder, what: str) -> None:
    """`RecorderError` "cannot write {what} to {folder}: why" unless ``folder``, or the nearest folder above
    it that exists, takes new files; nothing is left behind (a temporary file is made and removed)."""
    folder = Path(folder).resolve()
    existing = next(p for p in (folder, *folder.parents) if p.exists())
    try:
        if not existing.is_dir():
            raise NotADirectoryError(f"{existing} is not a folder")
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise RecorderError(f"cannot write {what} to {folder}: {existing} takes no files "
                            f"({exc.strerror or exc})") from None


def check_folder(folder, what: str) -> Path:
    """:func:`check_creatable`, then make ``folder`` where missing. Returns it as a Path."""
    check_creatable(folder, what)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def recording_id(app_id: str, meta: Mapping[str, Any]) -> str:
    """A UUID derived from the application id and the run metadata: the same run gives the same id."""
    text = json.dumps({"app_id": app_id, "meta": schema.encode_meta(meta)}, sort_keys=True)
    return str(uuid.UUID(bytes=hashlib.sha256(text.encode()).digest()[:16]))


class Recorder:
    """Record one run to `out.rrd` and/or `out.mcap` (see the package docstring for the file layout).

    Args:
        out: output path without suffix (a .rrd/.mcap suffix is dropped); parent folders are created.
        run_meta: JSON-serialisable run metadata (scenario, links, seed, settings, versions ...);
            `run_id` names the run (default: the file name). Keys of `schema.RUN_TABLE_COLUMNS`
            other than run_id are reserved.
        formats: subset of ("rrd", "mcap").
        overwrite: replace existing files; otherwise an existing output raises `RecorderError`.
        mcap_mesh_every: write the robot mesh to the MCAP on steps where `step % mcap_mesh_every == 0`
            (the mesh is most of the MCAP cost; Rerun logs it every step).
        flush_every: flush both files every this many steps; a SIGKILL loses at most these.
        safety_margin: metres; drawn as a line beside the distances in Rerun, and the margin of the
            clearance colour map (`recorder.style`).
        goal_tolerance: metres; the goal is drawn as a translucent sphere of this radius (with the
            approach axis of a pose goal) in both formats, and as a line beside the distances in Rerun.
            Kept as `self.goal_tolerance`.
        viewer: also stream the run live to a Rerun Viewer: True (one listening on this machine's
            default port, else a newly started one) or a URL "rerun+http://HOST:PORT/proxy". The files
            are written the same either way; without a reachable viewer a `ViewerWarning` says why
            and the run is recorded to files only (see `recorder.viewer`).
        app_id: Rerun application id.

    Files are opened at construction (after the path checks); SIGINT/SIGTERM handlers are installed
    while the recorder is open (main thread only) and the previous ones restored on close. A first
    signal lets the current step finish: the next `log_step` records it, then raises
    `RecordingInterrupted`; a second signal raises at once. Leaving a `with` block without `finish()`
    writes the outcome "interrupted" and closes both files.
    """

    def __init__(
        self,
        out: str | Path,
        run_meta: Mapping[str, Any],
        formats=FORMATS,
        *,
        overwrite: bool = False,
        mcap_mesh_every: int = MCAP_MESH_EVERY,
        flush_every: int = 50,
        safety_margin: float | None = None,
        goal_tolerance: float | None = None,
        viewer: bool | str = False,
        app_id: str = "ncedf",
    ):
        if mcap_mesh_every < 1 or flush_every < 1:
            raise ValueError("mcap_mesh_every and flush_every must be >= 1")
        for name, value in (("safety_margin", safety_margin), ("goal_tolerance", goal_tolerance)):
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite distance >= 0 in metres, got {value!r}")
        reserved = set(run_meta) & (set(schema.RUN_TABLE_COLUMNS) - {"run_id"})
        if reserved:
            raise ValueError(f"run_meta keys {sorted(reserved)} are reserved for the run table")
        self.paths = output_paths(out, formats)
        meta = dict(run_meta)
        meta.setdefault("run_id", next(iter(self.paths.values())).stem)
        schema.encode_meta(meta)  # fail early on unserialisable metadata
        check_writable(self.paths, overwrite)

        self.run_meta = meta
        self.safety_margin = safety_margin
        self.goal_tolerance = goal_tolerance
        self._flush_every = flush_every
        self._triangles: np.ndarray | None = None
        self._steps = 0
        self._last = (0, 0)  # (step, sim_time_ns) of the last step, for text and the outcome
        self._min_true = math.inf
        self._signal: int | None = None
        self._previous_handlers: dict[int, Any] = {}
        live = live_viewer.resolve(viewer)
        self._sinks = self._open_sinks(overwrite, app_id, mcap_mesh_every, live)
        for sink in self._sinks:
            sink.log_run(meta)
        self._install_handlers()

    def _open_sinks(self, overwrite: bool, app_id: str, mcap_mesh_every: int,
                    live: live_viewer.ViewerTarget | None) -> list:
        """The sinks of `self.paths`; the live viewer goes with the Rerun sink (one without a file if no .rrd)."""
        rerun_paths = [self.paths.get("rrd")] if "rrd" in self.paths or live is not None else []
        sinks, path = [], None
        try:
            for path in rerun_paths:
                from recorder.rerun_sink import RerunSink

                sinks.append(RerunSink(path, app_id=app_id, recording_id=recording_id(app_id, self.run_meta),
                                       run_name=str(self.run_meta["run_id"]), safety_margin=self.safety_margin,
                                       goal_tolerance=self.goal_tolerance, live=live))
            if "mcap" in self.paths:
                path = self.paths["mcap"]
                from recorder.mcap_sink import McapSink

                sinks.append(McapSink(path, overwrite=overwrite, mesh_every=mcap_mesh_every,
                                      goal_tolerance=self.goal_tolerance))
        except Exception as exc:
            for sink in sinks:
                sink.close(schema.normalise_outcome({"outcome": "interrupted"}))
            raise RecorderError(f"cannot open {path or 'the viewer stream'}: {exc}") from exc
        return sinks

    @property
    def live(self) -> bool:
        """Whether the run is being streamed to a viewer (False after a `ViewerWarning`)."""
        return any(getattr(sink, "live", False) for sink in self._sinks)

    # ------------------------------------------------------------ signals
    def _install_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in _SIGNALS:
            self._previous_handlers[sig] = signal.signal(sig, self._on_signal)

    def _restore_handlers(self) -> None:
        for sig, handler in self._previous_handlers.items():
            signal.signal(sig, handler)
        self._previous_handlers.clear()

    def _on_signal(self, signum: int, frame) -> None:
        if self.closed:  # closing already: let it finish
            return
        if self._signal is not None:
            raise RecordingInterrupted(f"signal {signal.Signals(signum).name} (second)", signum)
        self._signal = signum

    # ------------------------------------------------------------ events
    @property
    def closed(self) -> bool:
        return not self._sinks

    def log_step(
        self,
        step: int,
        sim_time: float,
        *,
        metrics: Mapping[str, float],
        mesh_vertices=None,
        mesh_triangles=None,
        backbone=None,
        obstacle_points=None,
        obstacle_shapes=None,
        goal=None,
        plan=None,
        state=None,
        link_clearance=None,
    ) -> None:
        """Record one step. Arrays may be numpy or JAX; units metres, radians, seconds.

        Args:
            step: step index (timeline `step`), increasing from call to call (one table row per step).
            sim_time: seconds (timeline `sim_time`, stored to 1 ns).
            metrics: {name: float}: goal_distance, predicted_min_distance, true_min_distance, solver_ms
                and any extra keys (NaN or None allowed). Training runs and benchmarks pass only metrics.
            mesh_vertices: (V, 3) robot surface; mesh_triangles: (F, 3) vertex indices, required with the
                first mesh, constant afterwards (logged once; a different topology raises ValueError).
            backbone: (M, K, 3) or a list of M (K_i, 3) polylines, one per link.
            obstacle_points: (P, 3) observed cloud. obstacle_shapes: {"spheres": {"centers": (S, 3),
                "radii": (S,)}, "boxes": {"centers": (B, 3), "sizes": (B, 3)}}.
            goal: position (3,) or pose (4, 4) (its z axis is the approach axis).
            plan: (H + 1, 3) planned end-effector path.
            state: {"arc_lengths": (M, 3), "theta": (M,), "phi": (M,), "ee_position": (3,)}.
            link_clearance: (M,) metres, the exact distance of each link to the nearest obstacle (negative:
                penetration). Colours each link (its V / M mesh vertices, V the mesh's vertex count, and its
                backbone polyline, one per link) by `recorder.style.clearance_colors` with the recorder's
                safety_margin (must then be > 0; None: `style.COLOR_MAP_MARGIN`). Not read back by `load_run`.
        """
        if self.closed:
            raise RecorderError(f"recorder for {self._describe()} is closed")
        s = make_step(step, sim_time, metrics, mesh_vertices=mesh_vertices, mesh_triangles=mesh_triangles,
                      backbone=backbone, obstacle_points=obstacle_points, obstacle_shapes=obstacle_shapes,
                      goal=goal, plan=plan, state=state, link_clearance=link_clearance,
                      safety_margin=self.safety_margin)
        if self._steps and s.step <= self._last[0]:
            raise ValueError(f"steps must increase: step {s.step} after step {self._last[0]}")
        if s.mesh_vertices is not None:
            self._check_topology(s.mesh_triangles, s.mesh_vertices.shape[0])
        for sink in self._sinks:
            sink.log_step(s)
        self._steps += 1
        self._last = (s.step, s.sim_time_ns)
        true_min = s.metrics.get("true_min_distance", math.nan)
        if true_min < self._min_true:
            self._min_true = true_min
        if self._steps % self._flush_every == 0:
            self.flush()
        if self._signal is not None:
            raise RecordingInterrupted(f"signal {signal.Signals(self._signal).name}", self._signal)

    def _check_topology(self, triangles: np.ndarray | None, n_vertices: int) -> None:
        if self._triangles is None:
            if triangles is None:
                raise ValueError("mesh_triangles is required with the first mesh_vertices")
            if triangles.size and triangles.max() >= n_vertices:
                raise ValueError(f"mesh_triangles index {triangles.max()} out of range for {n_vertices} vertices")
            self._triangles = triangles
        elif triangles is not None and triangles is not self._triangles and not np.array_equal(triangles,
                                                                                               self._triangles):
            raise ValueError(f"mesh topology changed: triangles {triangles.shape} differ from the first "
                             f"{self._triangles.shape}; the recorder logs the topology once")

    def log_text(self, message: str, level: str = "info") -> None:
        """A text line (levels debug, info, warning, error, critical) at the last step's time."""
        for sink in self._sinks:
            sink.log_text(message, level, *self._last)

    def log_meshes(self, meshes) -> None:
        """The world's still meshes, once before the steps: (vertices (V, 3) m, faces (F, 3) indices) each,
        drawn beside the observed points (``schema.OBSTACLE_MESHES``)."""
        meshes = [(np.asarray(v, np.float32), np.asarray(f, np.uint32)) for v, f in meshes]
        for v, f in meshes:
            if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or (f.size and f.max() >= len(v)):
                raise ValueError(f"a mesh needs vertices (V, 3) and faces (F, 3) indexing them, "
                                 f"got {v.shape}, {f.shape}")
        for sink in self._sinks:
            sink.log_meshes(meshes)

    def flush(self) -> None:
        for sink in self._sinks:
            sink.flush()

    def finish(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome ({"outcome": success|collision|stuck|interrupted, "steps", "reach_step",
        "min_true_distance", "first_collision_step"}; missing fields are None) and close the files."""
        clean = schema.normalise_outcome(outcome)
        sinks, self._sinks = self._sinks, []
        try:
            for sink in sinks:
                sink.close(clean)
        finally:
            self._restore_handlers()

    def interrupted_outcome(self) -> dict[str, Any]:
        """The outcome written when the run ends without `finish()`: what was logged so far."""
        return {
            "outcome": "interrupted",
            "steps": self._steps,
            "min_true_distance": self._min_true if math.isfinite(self._min_true) else None,
        }

    def _describe(self) -> str:
        return " and ".join(str(p) for p in self.paths.values())

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self.closed:
            self.finish(self.interrupted_outcome())
