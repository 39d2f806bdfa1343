"""The report's PNG figures, each written atomically.

Drawn on matplotlib ``Figure`` objects of their own, never through pyplot: a notebook's backend
and figures stay as they were (``matplotlib.use("Agg")`` here switched an inline backend away).

* ``hypotheses.png``: hypothesis count per keyframe (the paper's figure 8);
* ``errors.png``: x, y and heading error per keyframe, best and belief-weighted (figures 9-11);
* ``map.png``: the map of places at their first-visit true positions (dead-reckoned odometry
  without ground truth), loop-closure links highlighted, the odometry path for comparison;
* ``pr.png``: loop-closure precision against recall as a threshold on the claim's belief
  sweeps down, as place-recognition work reports it: where to set a threshold, and what it costs;
* ``trajectory.png``: the embedded map's trajectory and odometry alone, aligned to the truth.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from aslam.app.score import Report
from aslam.core.metrics import Evaluation
from aslam.core.se2 import dead_reckoning
from aslam.data_formats.estimate import EstimateGraph
from aslam.data_formats.files import (
    check_output_folder,
    check_output_path,
    make_output_folder,
    remove_superseded,
    write_atomically,
)
from aslam.data_formats.graph_json import is_loop_closure_link

DPI = 120
PLOT_NAMES = ("hypotheses.png", "errors.png", "map.png", "pr.png", "trajectory.png")
"""The figures ``write_plots`` may write (the last only where the map has a metric view: a run of one
keyframe or more)."""


def _save(fig: Any, path: Path) -> None:
    def write(temporary: Path) -> None:
        fig.savefig(temporary, format="png", dpi=DPI)

    write_atomically(path, write)


def write_plots(
    folder: Path | str,
    report: Report,
    *,
    force: bool = False,
    on_warning: Callable[[str], None] | None = None,
) -> list[Path]:
    """Write the figures into ``folder`` (created if missing); returns their paths. Every figure's
    path is checked before any is drawn: one that exists is refused unless ``force``, as
    ``export_trajectories`` refuses its files. ``on_warning`` hears of a figure left out (the
    trajectory of an estimate without keyframes).

    Drawn with matplotlib's default style, not the settings of a matplotlibrc (the user's, or one in
    the current folder, which matplotlib also reads): the same report gives the same bytes anywhere.
    """
    import matplotlib.style

    folder = Path(folder)
    check_output_folder(folder, what="plots folder")
    if folder.is_dir():
        for name in PLOT_NAMES:
            check_output_path(folder / name, force=force)
    title = report.estimate_path.name
    make_output_folder(folder)
    paths = [folder / name for name in PLOT_NAMES[:4]]
    with matplotlib.style.context("default"):
        _save(_hypotheses_figure(report.evaluation, title), paths[0])
        _save(_errors_figure(report.evaluation, title, measured=not report.truth_by_index), paths[1])
        map_truth = None if report.true_poses is None else report.map_truth
        _save(
            _map_figure(report.estimate.graph, report.actions, report.true_poses, title, map_truth), paths[2]
        )
        _save(_pr_figure(report.evaluation, report.summary["committed"], title), paths[3])
        if report.embedding is not None:
            paths.append(folder / PLOT_NAMES[4])
            _save(_trajectory_figure(report, title), paths[-1])
        else:
            remove_superseded(folder / PLOT_NAMES[4], force=force)  # an earlier run's, with force
            if on_warning is not None:
                on_warning(f"{folder / PLOT_NAMES[4]}: not drawn: the estimate has no keyframes")
    return paths


def _aligned(poses: np.ndarray, truth: np.ndarray, stamps_ns: np.ndarray) -> np.ndarray:
    """``poses`` (rows where the truth is known) moved onto the truth by evo's Umeyama alignment."""
    import copy

    from aslam.data_formats.trajectory import evo_trajectory

    estimate = copy.deepcopy(evo_trajectory(poses, stamps_ns))
    estimate.align(evo_trajectory(truth, stamps_ns), correct_scale=False)
    return np.asarray(estimate.positions_xyz)[:, :2]


def _trajectory_figure(report: Report, title: str) -> Any:
    """The embedded trajectory and odometry alone, aligned to the truth as evo aligns them for APE."""
    from matplotlib.figure import Figure

    assert report.embedding is not None
    fig = Figure(figsize=(7.5, 7.5), layout="constrained")
    ax = fig.subplots()
    optimised, odometry = report.embedding.poses, report.embedding.odometry
    truth = report.true_poses
    known = None if truth is None else np.isfinite(truth).all(axis=1)
    if truth is not None and known is not None and known.sum() >= 2:
        stamps = np.asarray(report.stamps_ns, dtype=np.int64)[known]
        ax.plot(truth[known, 0], truth[known, 1], "-", color="0.6", linewidth=2.5, label="ground truth")
        from evo.core.geometry import GeometryException

        try:
            odometry_xy = _aligned(odometry[known], truth[known], stamps)
            optimised_xy = _aligned(optimised[known], truth[known], stamps)
            frame = "aligned to the ground truth (evo, Umeyama SE(3))"
        except GeometryException:  # every position on one line: no unique rotation to align by
            odometry_xy, optimised_xy = odometry[:, :2], optimised[:, :2]
            frame = "in the frame of the first keyframe (a straight run cannot be aligned)"
    else:
        odometry_xy, optimised_xy = odometry[:, :2], optimised[:, :2]
        known_poses = 0 if known is None else int(known.sum())
        frame = "in the frame of the first keyframe " + (
            "(no ground truth)" if not known_poses else "(truth at one pose only)"
        )
    # A run of one keyframe: a point, not a line.
    one: dict[str, Any] = {"marker": "o"} if len(optimised) == 1 else {}
    ax.plot(*odometry_xy.T, "--", color="tab:gray", linewidth=1, label="odometry alone", **one)
    ax.plot(*optimised_xy.T, "-", color="tab:blue", linewidth=1.2, label="embedded map", **one)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Trajectory {frame}\n{title}")
    ax.legend(loc="best", fontsize="small")
    return fig


def _pr_figure(evaluation: Evaluation, committed: dict[str, Any], title: str) -> Any:
    """Precision against recall over a threshold on the claim's belief (highest first), the
    best hypothesis's own operating point (every claim: the lowest threshold) and the final map's."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 5.5), layout="constrained")
    ax = fig.subplots()
    curve = evaluation.pr_curve() if evaluation.has_ground_truth else None
    if curve is None or curve.revisits == 0:
        why = "no ground truth" if curve is None else "no true revisit to find"
        ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center", color="0.4")
        subtitle = why
    elif not len(curve.recall):
        ax.text(0.5, 0.5, "no loop closure claimed", transform=ax.transAxes, ha="center", va="center")
        subtitle = f"{curve.revisits} true revisits, none claimed"
    else:
        # From (0, first precision): a threshold above every belief keeps no claim.
        recall = np.concatenate([[0.0], curve.recall])
        precision = np.concatenate([curve.precision[:1], curve.precision])
        ax.step(recall, precision, where="pre", color="tab:blue", linewidth=1.5, label="belief ≥ threshold")
        points = ax.scatter(
            curve.recall,
            curve.precision,
            c=curve.thresholds,
            cmap="viridis",
            vmin=0.0,
            vmax=1.0,
            s=18,
            zorder=3,
        )
        fig.colorbar(points, ax=ax, label="threshold on the claim's belief")
        ax.plot(
            curve.recall[-1],
            curve.precision[-1],
            "o",
            markersize=11,
            markerfacecolor="none",
            markeredgecolor="tab:red",
            markeredgewidth=1.5,
            label="best hypothesis (every claim)",
        )
        if committed.get("precision") is not None and committed.get("recall") is not None:
            ax.plot(
                committed["recall"],
                committed["precision"],
                "s",
                markersize=9,
                markerfacecolor="none",
                markeredgecolor="tab:orange",
                markeredgewidth=1.5,
                label="final map (committed)",
            )
        full = curve.recall_at_full_precision
        if full:
            ax.axvline(full, color="0.5", linestyle=":", linewidth=1, label="recall at 100 % precision")
        subtitle = (
            f"AUC {curve.auc:.3f}, recall at 100 % precision {full:.3f}, "
            f"{int(evaluation.claims.sum())} claims, {curve.revisits} true revisits"
        )
        ax.legend(loc="lower left", fontsize="small")
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("recall (true revisits claimed)")
    ax.set_ylabel("precision (claims right)")
    ax.grid(True, alpha=0.3)
    ax.set_title(f"Loop closures over a belief threshold — {title}\n{subtitle}", fontsize="medium")
    return fig


def _revisit_spans(ax: Any, evaluation: Evaluation) -> None:
    """Shade the keyframes that truly revisit a place (light grey)."""
    revisit = evaluation.true_revisit
    t = 0
    labelled = False
    while t < len(revisit):
        if revisit[t]:
            start = t
            while t < len(revisit) and revisit[t]:
                t += 1
            ax.axvspan(
                start - 0.5,
                t - 0.5,
                color="0.88",
                zorder=0,
                label=None if labelled else "true revisit",
            )
            labelled = True
        else:
            t += 1


def _hypotheses_figure(evaluation: Evaluation, title: str) -> Any:
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    fig = Figure(figsize=(9, 3.6), layout="constrained")
    ax = fig.subplots()
    counts = evaluation.hypothesis_counts
    keyframes = np.arange(len(counts))
    _revisit_spans(ax, evaluation)
    ax.step(keyframes, counts, where="mid", color="tab:blue", linewidth=1.5, label="hypotheses")
    claims = np.flatnonzero(evaluation.claims)
    if claims.size:
        ax.plot(claims, counts[claims], "|", color="tab:orange", markersize=10, label="best says revisit")
    ax.set_xlabel("keyframe")
    ax.set_ylabel("hypotheses")
    ax.set_ylim(0, max(int(counts.max()) if counts.size else 1, 1) * 1.15)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts: no 1.5 hypotheses
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlim(-0.5, max(len(counts) - 0.5, 0.5))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize="small")
    ax.set_title(f"Hypotheses per keyframe — {title}")
    return fig


ERROR_AXIS_MIN = 0.05
"""The least top of an error axis (m or °): errors of a right claim are rounding (1e-16 m), which an
axis scaled to them would draw as large as errors of a metre."""


def _errors_figure(evaluation: Evaluation, title: str, *, measured: bool) -> Any:
    """``measured``: False for a truth by index, whose "errors" are frame numbers, not poses."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    fig = Figure(figsize=(9, 7.5), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    keyframes = np.arange(evaluation.keyframes)
    names = [("x error (m)", 0), ("y error (m)", 1), ("heading error (°)", 2)]
    for ax, (label, column) in zip(axes, names, strict=True):
        _revisit_spans(ax, evaluation)
        if measured:
            best = np.abs(evaluation.best_error[:, column])
            weighted = evaluation.weighted_error[:, column]
            ax.plot(keyframes, best, "o", color="tab:red", markersize=3.5, label="best hypothesis")
            ax.plot(
                keyframes, weighted, "-", color="tab:blue", linewidth=1.0, alpha=0.8, label="belief-weighted"
            )
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.set_ylim(0, max(ax.get_ylim()[1], ERROR_AXIS_MIN))
    why = None
    if not evaluation.has_ground_truth:
        why = "no ground truth"
    elif not measured:
        why = "not measured (a truth by index has frame numbers, not poses)"
    if why is not None:
        axes[0].text(0.5, 0.5, why, transform=axes[0].transAxes, ha="center", va="center", color="0.4")
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1].set_xlabel("keyframe")
    axes[-1].set_xlim(-0.5, max(evaluation.keyframes - 0.5, 0.5))
    if axes[0].get_legend_handles_labels()[0]:  # by index with no revisit: nothing drawn to name
        axes[0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize="small", frameon=False)
    fig.suptitle(f"Revisit errors (absolute; new-state hypotheses excluded) — {title}")
    return fig


def _map_figure(
    graph: EstimateGraph,
    actions: np.ndarray,
    true_poses: np.ndarray | None,
    title: str,
    map_truth: np.ndarray | None = None,
) -> Any:
    """``true_poses``: this run's keyframes' truth; ``map_truth``: every keyframe's of the map (a run
    in a prior map: the map's sessions', then this run's), where the places are drawn."""
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 7.5), layout="constrained")
    ax = fig.subplots()
    has_truth = true_poses is not None and bool(np.isfinite(true_poses).all(axis=1).any())
    start = np.zeros(3)
    if has_truth:
        assert true_poses is not None
        start = true_poses[np.flatnonzero(np.isfinite(true_poses).all(axis=1))[0]]
    # Odometry, drawn from the first true pose: the keyframe actions composed.
    odometry = dead_reckoning(actions, start)
    first = graph.first_keyframe
    position: dict[int, np.ndarray] = {}
    later = 0  # places drawn at a later visit: their first visit's truth is unknown
    for state in graph.states:  # state ids are keyframes of the whole map, prior sessions first
        if has_truth:
            truth = true_poses if map_truth is None else map_truth
            assert truth is not None
            offset = 0 if map_truth is not None else first
            known = [
                k - offset
                for k in (state.id, *sorted(state.keyframes))
                if 0 <= k - offset < len(truth) and np.isfinite(truth[k - offset][:2]).all()
            ]
            pose = truth[known[0]] if known else None
            later += bool(known) and known[0] != state.id - offset
        else:  # where this run first was at the place by odometry (a prior place it never visited: not drawn)
            visits = [k - first for k in state.keyframes if first <= k < first + len(odometry)]
            pose = odometry[min(visits)] if visits else None
        if pose is not None and np.isfinite(pose[:2]).all():
            position[state.id] = pose[:2]
    if has_truth:
        assert true_poses is not None
        ok = np.isfinite(true_poses).all(axis=1)
        ax.plot(true_poses[ok, 0], true_poses[ok, 1], "-", color="0.75", linewidth=1, label="true path")
    ax.plot(
        odometry[:, 0], odometry[:, 1], "--", color="tab:gray", linewidth=1, label="odometry (dead reckoning)"
    )
    normal: list[list[np.ndarray]] = []
    closing: list[list[np.ndarray]] = []
    for link in graph.links:
        a, b = link.from_state, link.to_state
        if a in position and b in position and a != b:
            (closing if is_loop_closure_link(a, b) else normal).append([position[a], position[b]])
    if normal:
        ax.add_collection(LineCollection(normal, colors="tab:blue", linewidths=1.5, label="link"))
    if closing:
        ax.add_collection(
            LineCollection(closing, colors="tab:red", linewidths=2.5, label="loop-closure link")
        )
    if position:
        xy = np.array(list(position.values()))
        visit_counts = {s.id: len(s.keyframes) for s in graph.states}
        revisited = np.array([visit_counts.get(s, 1) > 1 for s in position])
        ax.plot(xy[~revisited, 0], xy[~revisited, 1], "o", color="tab:blue", markersize=5, label="place")
        if revisited.any():
            ax.plot(
                xy[revisited, 0],
                xy[revisited, 1],
                "o",
                markerfacecolor="white",
                markeredgecolor="tab:red",
                markeredgewidth=2,
                markersize=8,
                label="place visited again",
            )
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    frame = "at first-visit true positions" if has_truth else "at dead-reckoned odometry positions"
    if later:
        frame += f" ({later} at a later visit: the first's truth unknown)"
    ax.set_title(f"Map of places {frame}\n{title}")
    ax.legend(loc="best", fontsize="small")
    return fig
