"""Recordings of runs: Rerun (.rrd) and MCAP (.mcap) files written from one event stream, read back into pandas.

The recorder takes arrays and names only (it imports nothing from `ncedf` or `scenarios`)::

    from recorder import Recorder, load_run, load_runs, load_summaries

    with Recorder("out/run-0", run_meta, safety_margin=0.05, goal_tolerance=0.2,
                  viewer=False) as rec:                                     # out/run-0.rrd + out/run-0.mcap
        for k in range(steps):
            rec.log_step(k, k * dt, metrics={...}, mesh_vertices=V, mesh_triangles=F, backbone=B,
                         obstacle_points=P, obstacle_shapes=S, goal=g, plan=H, state={...},
                         link_clearance=d)
        rec.finish({"outcome": "success", "steps": steps, "reach_step": r,
                    "min_true_distance": d, "first_collision_step": None})
    run = load_run("out/run-0.mcap")          # Run(meta, metrics, state, outcome, complete)
    runs, steps = load_runs("out")            # one row per run; long per-step metrics
    table = load_summaries("out")             # one row per run with per-metric count/mean/std/min/max

Training runs and benchmarks use the same `Recorder` with only `metrics` per step.

Where each event goes (names in `recorder.schema`; MCAP topics = Rerun entity paths):

| event | Rerun (.rrd) | MCAP (.mcap) |
| --- | --- | --- |
| `/run` metadata | recording property `run`, one key per metadata key, value = JSON text | metadata record `run`, same {key: JSON text} |
| `/world/robot/mesh` | Mesh3D: triangle indices static (once), vertex positions (+ colours) every step | foxglove.SceneUpdate, one triangle list, per-vertex colours with clearances (every `mcap_mesh_every`-th step) |
| `/world/robot/backbone` | LineStrips3D, one strip per link (+ colours) | foxglove.SceneUpdate, one line strip per link, in its link's colour |
| `/world/obstacles/points` | Points3D | foxglove.PointCloud (x, y, z float32) |
| `/world/obstacles/shapes` | `.../spheres` Ellipsoids3D, `.../boxes` Boxes3D | foxglove.SceneUpdate (spheres, cubes) |
| `/world/obstacles/meshes` | `.../<i>` Mesh3D, static | foxglove.SceneUpdate at time 0 (a triangle list per mesh) |
| `/world/goal` | Transform3D + a point at its origin | foxglove.FrameTransform world -> goal |
| `/world/goal_marker` (with `goal_tolerance`) | `.../region` Ellipsoids3D (sphere of the tolerance), `.../approach` Arrows3D (pose goals) | foxglove.SceneUpdate (sphere, arrow) |
| `/world/plan` | LineStrips3D + Points3D at the knots | foxglove.SceneUpdate line strip + a sphere per knot |
| `/state` | Scalars `/state/arc_lengths` (3M), `/state/theta`, `/state/phi` (M), `/state/ee_position` (3) | JSON `ncedf.State` |
| `/metrics` | Scalars `/metrics/<name>` | JSON `ncedf.Metrics` (NaN as null) |
| `/outcome` | recording property `outcome` (JSON text per field) | JSON `ncedf.Outcome`, the last message |
| summary (on close) | - (`load_summaries` computes it from the rows) | metadata record `summary`: outcome + per-metric statistics (`recorder.summary`), indexed in the summary section |
| `/log` text | TextLog | foxglove.Log |

Rerun: timelines `step` and `sim_time` (wall clock off), a stored blueprint with a view for each kind
of data the run logs (3D view of `/world` on a dark background; the goal distance with the goal tolerance
`/reference/goal_tolerance`; the clearances with the safety margin `/reference/safety_margin`; solver
time; the other metrics; the log of the run's events), no empty plot: a closed-loop run's layout is stored
at the start, another one sent where the steps log other data.
MCAP: log_time = sim_time in ns. Scalars are float64 in both formats; `sim_time` is kept to 1 ns.

Display (`recorder.style`): links coloured by `link_clearance` from red (collision) through orange
(at the safety margin) and yellow to green and blue (1 m and more); the plan a thick cyan line with
its knots; the observed points white, 4 cm; the goal magenta, with a translucent sphere of the goal
tolerance and, for a pose goal, an arrow along its approach (z) axis.

Live: `viewer=True` (or a URL) also streams the run to a Rerun Viewer (`recorder.viewer`); the
files are written the same, and without a viewer one `ViewerWarning` says why.

Reproducibility: the Rerun recording id is derived from app id + metadata and nothing wall-clock
is logged, yet rerun-sdk 0.41 stamps every chunk and row with a time-based id, so two .rrd files of
the same run are equal by `rerun rrd compare --unordered` but not byte for byte. The .mcap is
byte-identical.

Faults: the files are written in place and flushed every `flush_every` steps. SIGINT/SIGTERM let the
current step finish, then write the outcome "interrupted" and close both files; after a SIGKILL
`load_run` reads what was flushed and warns `IncompleteRecordingWarning`. An existing output is
refused unless `overwrite=True`; an unwritable folder fails before anything is opened
(`RecorderError`, one line naming the path).

Cost: `python bench/recording_cost.py` measures the time per step and the file sizes. A live viewer
adds one `send_columns` per entity and step on a second stream.

Many runs in one process: rerun-sdk keeps each recording's threads and some memory alive until the
process ends (rerun-io/rerun#2116), so record thousands of runs from worker processes that are
replaced now and then (e.g. `ProcessPoolExecutor(max_tasks_per_child=...)`).

CLI: `python -m recorder.inspect FILE...`; `python -m recorder.synthetic OUT` writes a synthetic run.
"""

from recorder.errors import RecorderError, RecordingInterrupted
from recorder.recorder import Recorder
from recorder.viewer import ViewerWarning

#: What ``recorder.read`` gives, imported on first use (it brings pandas: slow to import for a runner).
_READ = ("IncompleteRecordingWarning", "Run", "load_run", "load_runs", "load_summaries")


def __getattr__(name: str):
    if name in _READ:
        from recorder import read

        return getattr(read, name)
    raise AttributeError(f"module 'recorder' has no attribute {name!r}")

__all__ = ["Recorder", "RecorderError", "RecordingInterrupted", "IncompleteRecordingWarning", "Run", "ViewerWarning",
           "load_run", "load_runs", "load_summaries"]
