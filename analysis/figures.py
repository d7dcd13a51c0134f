"""The paper's figures from recordings (and, for Fig. 3 only, from the model itself).

Each builder returns ``(matplotlib Figure, pandas DataFrame of the plotted data)`` or a one-line
note saying why it was skipped. Styling for a paper column: 3.5 in wide, 8 pt text, black and grey
with distinct line styles and markers so the figures survive greyscale printing.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.patches import Circle, Rectangle  # noqa: E402

from analysis import paper  # noqa: E402
from analysis.load import Recordings, pooled  # noqa: E402
from recorder.read import load_snapshots as snapshots  # noqa: E402
from analysis.stats import wilson  # noqa: E402
from recorder import load_run  # noqa: E402

COLUMN_IN = 3.5
#: The fixed axis of each timing figure (scenarios.reproduce's timing experiment): 4 links, 500 points.
TIMING_LINKS, TIMING_POINTS = 4, 500
STYLES = [dict(color="black", linestyle="-", marker="o"), dict(color="0.45", linestyle="--", marker="s"),
          dict(color="0.2", linestyle=":", marker="^"), dict(color="0.6", linestyle="-.", marker="D"),
          dict(color="0.35", linestyle=(0, (5, 1, 1, 1)), marker="v")]
plt.rcParams.update({"font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "legend.fontsize": 7,
                     "xtick.labelsize": 7, "ytick.labelsize": 7, "savefig.dpi": 200, "savefig.bbox": "tight"})


def _pick(runs: pd.DataFrame, prefer_shape: str = "ncedf") -> pd.Series | None:
    """A representative run: the preferred shape, full (not quick) runs first, then the paper's goal, a success
    first."""
    if runs.empty:
        return None
    key = pd.DataFrame({"quick": runs["quick"].astype(bool), "shape": runs["shape"] != prefer_shape,
                        "goal": runs["goal_kind"] != "fixed", "fail": runs["outcome"] != "success",
                        "path": runs["path"]})
    return runs.loc[key.sort_values(["quick", "shape", "goal", "fail", "path"]).index[0]]


# ---------------------------------------------------------------- Fig. 3
#: Link configurations of Fig. 3: (theta, phi) rad.
FIG3_CONFIGS = ((0.8, 0.0), (2.0, math.pi / 3))
FIG3_GRID = 161


def fig3(model_path: str | None = None):
    """N-CEDF slices through the bending plane of one link: learned, exact and their difference."""
    import jax
    import jax.numpy as jnp

    from ncedf.data import BOX_MAX, BOX_MIN
    from ncedf.geometry import link_signed_distance
    from ncedf.model import load_model

    model = load_model(model_path)
    u = np.linspace(BOX_MIN[0], BOX_MAX[0], FIG3_GRID)
    z = np.linspace(BOX_MIN[2], BOX_MAX[2], FIG3_GRID)
    uu, zz = np.meshgrid(u, z)
    fig, axes = plt.subplots(len(FIG3_CONFIGS), 3, figsize=(2 * COLUMN_IN, 1.75 * len(FIG3_CONFIGS)),
                             constrained_layout=True)
    rows = []
    for i, (theta, phi) in enumerate(FIG3_CONFIGS):
        d = np.array([math.cos(phi), math.sin(phi), 0.0])  # the bending direction in the link frame
        pts = uu.reshape(-1, 1) * d + zz.reshape(-1, 1) * np.array([0.0, 0.0, 1.0])
        p = jnp.asarray(pts, jnp.float32)
        learned = np.asarray(jax.jit(model.link_distance)(p, theta, phi)).reshape(uu.shape)
        exact = np.abs(np.asarray(link_signed_distance(p, theta, phi, model.spec))).reshape(uu.shape)
        diff = learned - exact
        vmax = float(max(learned.max(), exact.max()))
        dmax = float(np.abs(diff).max())
        for j, (field, title, cmap, lim) in enumerate((
                (learned, "learned N-CEDF", "Greys", (0, vmax)), (exact, "exact distance", "Greys", (0, vmax)),
                (diff, "learned - exact (- - < 0)", "PuOr", (-dmax, dmax)))):
            ax = axes[i, j]
            im = ax.pcolormesh(uu, zz, field, cmap=cmap, vmin=lim[0], vmax=lim[1], shading="auto", rasterized=True)
            if j < 2:
                cs = ax.contour(uu, zz, field, levels=[0.25, 0.5, 1.0, 1.5], colors="k", linewidths=0.5)
                ax.clabel(cs, fontsize=6, fmt="%.2f")
            else:  # dashed: under-estimation, solid: over-estimation (reads in greyscale)
                ax.contour(uu, zz, diff, levels=[-0.05, -0.02, 0.02, 0.05], colors="k", linewidths=0.5)
                ax.contour(uu, zz, exact, levels=[0.02], colors="0.4", linewidths=0.6)
            ax.set_aspect("equal")
            if i == 0:
                ax.set_title(title)
            if i == len(FIG3_CONFIGS) - 1:
                ax.set_xlabel("u, along bending direction (m)")
            ax.set_ylabel(f"θ = {theta:.2f}, φ = {phi:.2f} rad\nz (m)" if j == 0 else "z (m)")
            fig.colorbar(im, ax=ax, shrink=0.55, aspect=12, label="distance (m)" if j < 2 else "error (m)")
        rows.append(pd.DataFrame({"config": i, "theta": theta, "phi": phi, "u": uu.ravel(), "z": zz.ravel(),
                                  "learned": learned.ravel(), "exact": exact.ravel(), "difference": diff.ravel()}))
    return fig, pd.concat(rows, ignore_index=True)


# ---------------------------------------------------------------- Fig. 4
def fig4(rec: Recordings):
    """Goal distance and robot-obstacle distances (predicted, exact) with the safety margin, one sphere run."""
    runs = rec.scenario("spheres")
    paper_robot = runs[[paper.table3_robot(n, r) for n, r in zip(runs["links"], runs["robot"])]] if len(runs) else runs
    run = _pick(paper_robot if len(paper_robot) else runs)  # Table III's robot where the folder has it
    if run is None:
        return "fig4: skipped, no dynamic-sphere recordings (python -m scenarios.reproduce table3 --out RUNS)"
    s = load_run(run["path"]).metrics
    margin = float(run["mppi.safety_margin"]) - float(run.get("world.margin_extra", 0.0) or 0.0)
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 2.4), constrained_layout=True)
    ax.plot(s["sim_time"], s["goal_distance"], label="end effector to goal", **STYLES[0], markevery=10, ms=3)
    ax.plot(s["sim_time"], s["predicted_min_distance"], label="robot to obstacles, predicted", **STYLES[1],
            markevery=10, ms=3)
    ax.plot(s["sim_time"], s["true_min_distance"], label="robot to obstacles, exact", **STYLES[2], markevery=10, ms=3)
    ax.axhline(margin, color="0.3", linewidth=0.8, linestyle=(0, (1, 2)), label=f"safety margin {margin:.2f} m")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("distance (m)")
    ax.set_title(f"{run['shape']}, {run['controller']}, environment {int(run['env_seed'])}: {run['outcome']}"
                 + (" (quick)" if run["quick"] else ""))
    ax.legend(loc="upper right", frameon=False)
    ax.set_ylim(bottom=min(0.0, float(np.nanmin(s["true_min_distance"]))))
    data = s[["step", "sim_time", "goal_distance", "predicted_min_distance", "true_min_distance"]].assign(
        safety_margin=margin, run=run["path"])
    return fig, data


# ---------------------------------------------------------------- Figs. 5-7
def _bounds(snaps) -> tuple[tuple[float, float], tuple[float, float]]:
    """x and z limits that hold the scene's boxes, every robot pose and plan shown, with 0.5 m to spare, m."""
    xs, zs = [-1.0, 7.0], [-1.0, 7.0]
    for snap in snaps:
        for line in [*snap.backbone, *([] if snap.plan is None or not len(snap.plan) else [snap.plan])]:
            xs += [line[:, 0].min(), line[:, 0].max()]
            zs += [line[:, 2].min(), line[:, 2].max()]
        for b in snap.boxes:
            xs += [b[0] - b[3] / 2, b[0] + b[3] / 2]
            zs += [b[2] - b[5] / 2, b[2] + b[5] / 2]
    return (min(xs) - 0.5, max(xs) + 0.5), (min(zs) - 0.5, max(zs) + 0.5)


def _draw(ax, snap, title: str, limits) -> None:
    """The scene seen from -y (x-z plane): boxes and spheres grey, points light grey, robot black, plan dashed."""
    for b in snap.boxes:
        ax.add_patch(Rectangle((b[0] - b[3] / 2, b[2] - b[5] / 2), b[3], b[5], facecolor="0.85", edgecolor="0.5",
                               linewidth=0.5))
    for s in snap.spheres:
        ax.add_patch(Circle((s[0], s[2]), s[3], facecolor="0.6", edgecolor="0.3", linewidth=0.5))
    if len(snap.points):
        ax.scatter(snap.points[:, 0], snap.points[:, 2], s=0.5, color="0.55", linewidths=0)
    for i, line in enumerate(snap.backbone):
        ax.plot(line[:, 0], line[:, 2], color="black" if i % 2 == 0 else "0.35", linewidth=2.2,
                solid_capstyle="round")
    if snap.plan is not None and len(snap.plan):
        ax.plot(snap.plan[:, 0], snap.plan[:, 2], color="black", linestyle="--", linewidth=0.8, marker=".", ms=2)
    if snap.goal is not None:
        ax.plot(snap.goal[0], snap.goal[2], marker="*", color="white", markeredgecolor="black", ms=9)
    ax.set_title(title)
    ax.set_aspect("equal")
    ax.set_xlim(*limits[0])
    ax.set_ylim(*limits[1])
    ax.set_xlabel("x (m)")


def snapshot_strip(rec: Recordings, links: int):
    """Figs. 5-7: a cluttered run with ``links`` links (the paper's goal and cloud density) at the paper's steps and
    its reach step."""
    runs = rec.scenario("cluttered")
    if not runs.empty:
        density = runs["world.density"] if "world.density" in runs else paper.TABLE4_DENSITY
        runs = runs[(runs["links"] == links) & (density == paper.TABLE4_DENSITY) & (runs["goal_kind"] == "fixed")]
    run = _pick(runs)
    if run is None:
        return f"cluttered L{links}: skipped, no {links}-link cluttered recordings " \
               f"(python -m scenarios.reproduce table4 --out RUNS)"
    full = load_run(run["path"])
    last = int(full.metrics["step"].max())
    steps = sorted({min(k, last) for k in paper.SNAPSHOT_STEPS.get(links, ())} | {0, last})
    times = dict(zip(full.metrics["step"], full.metrics["sim_time"]))
    snaps = snapshots(run["path"], {k: times[k] for k in steps})
    limits = _bounds(snaps.values())
    aspect = (limits[1][1] - limits[1][0]) / (limits[0][1] - limits[0][0])
    fig, axes = plt.subplots(1, len(steps), figsize=(1.3 * len(steps) + 0.4, 1.3 * aspect + 0.9), sharey=True,
                             layout="constrained")
    reach = run["reach_step"]
    rows = []
    for ax, k in zip(np.atleast_1d(axes), steps):
        label = "reached" if (pd.notna(reach) and k == int(reach)) else ("end" if k == last else "")
        _draw(ax, snaps[k], f"step {k}" + (f" ({label})" if label else ""), limits)
        sn = snaps[k]
        for i, line in enumerate(sn.backbone):
            rows.append(pd.DataFrame({"step": k, "kind": f"backbone_link{i + 1}", "x": line[:, 0], "y": line[:, 1],
                                      "z": line[:, 2]}))
        if sn.plan is not None:
            rows.append(pd.DataFrame({"step": k, "kind": "plan", "x": sn.plan[:, 0], "y": sn.plan[:, 1],
                                      "z": sn.plan[:, 2]}))
        rows.append(pd.DataFrame({"step": k, "kind": "sphere_centre", "x": sn.spheres[:, 0], "y": sn.spheres[:, 1],
                                  "z": sn.spheres[:, 2]}))
    np.atleast_1d(axes)[0].set_ylabel("z (m)")
    fig.suptitle(f"{links} links, {run['controller']} controller, seed {int(run['seed'])}: {run['outcome']}"
                 + (" (quick)" if run["quick"] else "") + f"; paper's steps {paper.SNAPSHOT_STEPS.get(links)}",
                 fontsize=8)
    return fig, pd.concat(rows, ignore_index=True).assign(run=run["path"])


# ---------------------------------------------------------------- timing and success
def _timing_plot(rec: Recordings, axis: str, label: str, fixed: str, value: int):
    """MPPI step time (mean ± std over the timed steps) against ``axis`` at ``fixed`` = ``value``, per
    representation (``python -m scenarios.reproduce timing``)."""
    runs = rec.scenario("timing")
    if not runs.empty:
        runs = runs[runs[fixed] == value]
    if runs.empty:
        return f"MPPI time vs {axis}: skipped, no timing recordings (python -m scenarios.reproduce timing --out RUNS)"
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 2.4), constrained_layout=True)
    order = {s: i for i, s in enumerate(paper.TABLE3)}
    groups = sorted(runs.groupby(["shape", "quick", "mppi.samples", "mppi.horizon"]),
                    key=lambda g: (order.get(g[0][0], 99), g[0]))
    rows = []
    for i, ((shape, quick, samples, horizon), g) in enumerate(groups):
        stats = []
        for x, gg in g.groupby(axis):
            mean, std, n = pooled(gg, "solver_ms")
            stats.append((x, mean / 1e3, std / 1e3, n))
        x, m, sd, n = (np.array(v) for v in zip(*stats))
        ax.errorbar(x, m, yerr=sd, capsize=2, ms=4, **STYLES[i % len(STYLES)],
                    label=f"{shape} ({int(samples)} samples, H {int(horizon)})" + (" quick" if quick else ""))
        rows.append(pd.DataFrame({"shape": shape, "quick": quick, "samples": int(samples), "horizon": int(horizon),
                                  fixed: value, axis: x, "mppi_step_s_mean": m, "mppi_step_s_std": sd,
                                  "timed_steps": n}))
    ax.set_xlabel(label)
    ax.set_ylabel("MPPI step time (s)")
    ax.set_yscale("log")
    if axis == "observed_points":
        ax.set_xscale("log")
    ax.set_xticks(sorted(runs[axis].unique()), [str(int(v)) for v in sorted(runs[axis].unique())])
    ax.minorticks_off()
    ax.set_title(f"{value} {'links' if fixed == 'links' else 'obstacle points'}, timed on the CPU")
    fig.legend(frameon=False, fontsize=6, loc="outside lower center", ncol=1)
    return fig, pd.concat(rows, ignore_index=True)


def mppi_time_vs_links(rec: Recordings):
    return _timing_plot(rec, "links", "robot links", "observed_points", TIMING_POINTS)


def mppi_time_vs_points(rec: Recordings):
    return _timing_plot(rec, "observed_points", "obstacle points", "links", TIMING_LINKS)


def success_rates(rec: Recordings):
    """Success rate per representation and controller with Wilson 95% intervals (dynamic spheres)."""
    runs = rec.scenario("spheres")
    if runs.empty:
        return "success rates: skipped, no dynamic-sphere recordings (python -m scenarios.reproduce table3 --out RUNS)"
    groups = list(runs.groupby(["links", "robot", "shape", "controller", "goal_kind", "quick"]))
    order = {s: i for i, s in enumerate(paper.TABLE3)}
    groups.sort(key=lambda g: (not paper.table3_robot(*g[0][:2]), int(g[0][0]), g[0][1], order.get(g[0][2], 99),
                               g[0][3], g[0][4]))
    rows = []
    for (links, robot, shape, controller, goal, quick), g in groups:
        n, k = len(g), int((g["outcome"] == "success").sum())
        low, high = wilson(k, n)
        ours = paper.table3_robot(links, robot)  # the paper's figure only beside its own robot
        rows.append({"links": int(links), "robot": robot, "shape": shape, "controller": controller, "goal": goal,
                     "quick": quick, "episodes": n, "successes": k, "success": k / n, "low": low, "high": high,
                     "paper_success": paper.table3_reference(shape, goal)[0] if ours else np.nan})
    df = pd.DataFrame(rows)
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 1.2 + 0.2 * len(df)), layout="constrained")
    y = np.arange(len(df))
    ax.errorbar(df["success"], y, xerr=[df["success"] - df["low"], df["high"] - df["success"]], fmt="o",
                color="black", capsize=2, ms=4, label="measured here, Wilson 95% interval")
    ax.plot(df["paper_success"], y, "x", color="0.45", ms=6, label="paper (1000 environments)")
    ax.set_yticks(y, [f"{r.shape}{paper.robot_tag(r.links, r.robot)}, {r.controller}"
                      + ("" if r.goal == "fixed" else f", {r.goal} goal")
                      + (" (quick)" if r.quick else "") + f" (n={r.episodes})" for r in df.itertuples()])
    ax.set_title("dynamic spheres; n: environments per row")
    ax.set_xlabel("success rate")
    ax.set_xlim(-0.02, 1.02)
    ax.invert_yaxis()
    fig.legend(frameon=False, loc="outside lower center", ncol=2, fontsize=6)
    return fig, df


def builders(rec: Recordings, model_path: str | None):
    """(file stem, thunk) of every figure."""
    return [
        ("fig3_ncedf_slices", lambda: fig3(model_path)),
        ("fig4_sphere_distances", lambda: fig4(rec)),
        *[(f"fig{5 + i}_cluttered_L{links}", (lambda l=links: snapshot_strip(rec, l)))
          for i, links in enumerate(sorted(paper.SNAPSHOT_STEPS))],
        ("mppi_time_vs_links", lambda: mppi_time_vs_links(rec)),
        ("mppi_time_vs_points", lambda: mppi_time_vs_points(rec)),
        ("success_rates", lambda: success_rates(rec)),
    ]

