"""A study's charts, PNG and SVG (matplotlib's Agg canvas, no pyplot state): speed against accuracy with
the Pareto fronts, held-out PSNR against Gaussian count with the smallest model within 0.5 dB of the
best, and — for tracked cells — held-out PSNR and tracking error frame by frame."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mmcsplat.storage.atomic import atomic_path
from mmcsplat.studies.cells import COMPLETE
from mmcsplat.studies.results import SMALLEST_WITHIN_DB, Aggregate, Findings, Row, pareto_front

PSNR_LABEL = "held-out masked PSNR (dB)"


def write_charts(folder: Path, rows: Sequence[Row], aggregates: Sequence[Aggregate], findings: Findings) -> list[tuple[str, str]]:
    """Write the charts that have data into ``folder``; returns (title, PNG file name) of each."""
    import matplotlib

    folder.mkdir(parents=True, exist_ok=True)
    scored = [a for a in aggregates if a.mean["val_masked_psnr"] is not None]
    charts = []
    with matplotlib.rc_context({"svg.hashsalt": "mmcsplat", "font.size": 9}):  # SVGs identical from run to run
        if scored:
            charts.append(("Speed against accuracy", _save(_speed_accuracy(rows, scored), folder, "speed_accuracy")))
            charts.append(("Held-out PSNR against Gaussian count", _save(_psnr_gaussians(scored, findings), folder, "psnr_gaussians")))
        tracked = [a for a in aggregates if a.series]
        if tracked:
            charts.append(("Tracked frames", _save(_dynamics(tracked), folder, "dynamics")))
    return charts


def _save(figure, folder: Path, stem: str) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(figure)
    for suffix in ("png", "svg"):
        with atomic_path(folder / f"{stem}.{suffix}") as temporary:
            figure.savefig(temporary, format=suffix, dpi=150, bbox_inches="tight", metadata={"Date": None} if suffix == "svg" else None)
    return f"{stem}.png"


def _colors(aggregates: Sequence[Aggregate]) -> dict[str, str]:
    return {a.label: f"C{i % 10}" for i, a in enumerate(aggregates)}


def _speed_accuracy(rows: Sequence[Row], scored: Sequence[Aggregate]):
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10, 4.2))
    colors = _colors(scored)
    groups = {(a.variant, a.session, a.backend): a for a in scored}
    for axis, key, minimize, title in ((figure.add_subplot(1, 2, 1), "wall_s", True, "fit wall time (s)"),
                                       (figure.add_subplot(1, 2, 2), "iterations_per_s", False, "iterations per second")):
        for row in rows:  # every complete cell, faint, behind its variant's mean
            group = groups.get((row.cell.variant, row.cell.session, row.cell.backend))
            x, y = getattr(row.outcome, key), row.outcome.val_masked_psnr
            if row.outcome.status == COMPLETE and group is not None and x is not None and y is not None:
                axis.scatter(x, y, s=12, color=colors[group.label], alpha=0.35, linewidths=0)
        usable = [a for a in scored if a.mean[key] is not None]
        points = [(a.mean[key], a.mean["val_masked_psnr"]) for a in usable]
        for a, (x, y) in zip(usable, points):
            axis.errorbar(x, y, yerr=a.std["val_masked_psnr"] or 0, fmt="o", color=colors[a.label], label=a.label, capsize=3)
        front = pareto_front(points, minimize)
        if front:
            axis.plot([points[i][0] for i in front], [points[i][1] for i in front], "--", color="0.3", lw=1, zorder=0, label="Pareto front")
            axis.scatter([points[i][0] for i in front], [points[i][1] for i in front], s=140, facecolors="none", edgecolors="0.2", zorder=3)
        xs = [x for x, _ in points]
        if xs and min(xs) > 0 and max(xs) / min(xs) > 20:
            axis.set_xscale("log")
        axis.set_xlabel(title + (" — lower is better" if minimize else " — higher is better"))
        axis.set_ylabel(PSNR_LABEL)
        axis.grid(alpha=0.3)
    figure.axes[0].legend(fontsize=7, loc="best")
    figure.suptitle("Speed against accuracy (circled: Pareto front)")
    return figure


def _psnr_gaussians(scored: Sequence[Aggregate], findings: Findings):
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6.5, 4.2))
    axis = figure.add_subplot(1, 1, 1)
    colors = _colors(scored)
    counted = [a for a in scored if a.mean["num_gaussians"] is not None]
    for a in counted:
        axis.errorbar(a.mean["num_gaussians"], a.mean["val_masked_psnr"], xerr=a.std["num_gaussians"] or 0,
                      yerr=a.std["val_masked_psnr"] or 0, fmt="o", color=colors[a.label], label=a.label, capsize=3)
    best = max(a.mean["val_masked_psnr"] for a in scored)
    axis.axhspan(best - SMALLEST_WITHIN_DB, best, color="0.85", zorder=0, label=f"within {SMALLEST_WITHIN_DB} dB of the best")
    smallest = next((a for a in counted if a.label == findings.smallest_within), None)
    if smallest is not None:
        axis.annotate(f"smallest within {SMALLEST_WITHIN_DB} dB:\n{smallest.label}", (smallest.mean["num_gaussians"], smallest.mean["val_masked_psnr"]),
                      xytext=(12, -28), textcoords="offset points", fontsize=8, arrowprops={"arrowstyle": "->", "color": "0.3"})
    counts = [a.mean["num_gaussians"] for a in counted]
    if counts and min(counts) > 0 and max(counts) / min(counts) > 20:
        axis.set_xscale("log")
    axis.set_xlabel("Gaussians at the end of the fit")
    axis.set_ylabel(PSNR_LABEL)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7, loc="best")
    axis.set_title("Model no more than a scene needs")
    return figure


def _dynamics(tracked: Sequence[Aggregate]):
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10, 4.2))
    colors = _colors(tracked)
    panels = (("per_frame_val_masked_psnr", PSNR_LABEL), ("tracking_per_frame_median_mm", "median 3D tracking error (mm)"))
    for index, (key, ylabel) in enumerate(panels):
        axis = figure.add_subplot(1, 2, index + 1)
        for a in tracked:
            series = a.series.get(key)
            if series:
                axis.plot(range(len(series)), [float("nan") if v is None else v for v in series], "-o", ms=3, color=colors[a.label], label=a.label)
        axis.set_xlabel("tracked frame")
        axis.set_ylabel(ylabel)
        axis.grid(alpha=0.3)
        if not axis.lines:
            axis.text(0.5, 0.5, "not measured (no ground truth or held-out masks)", ha="center", va="center", transform=axis.transAxes, color="0.4")
        else:
            axis.legend(fontsize=7, loc="best")
    figure.suptitle("Frame by frame (mean over folds and seeds)")
    return figure
