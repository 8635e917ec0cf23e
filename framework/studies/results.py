"""A study's results: one row per cell, aggregates per variant (mean and standard deviation over folds and
seeds), the findings (best variant, the smallest model within 0.5 dB of it, Pareto fronts of speed
against accuracy), written as results.json, results.csv and a markdown table in the reference study's
columns — mask, λ_seg, sparse, #init points, init range, val PSNR, train PSNR — read off each resolved
configuration, plus wall time, iterations per second, Gaussian count and backend.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.configuration.config import Config
from mmcsplat.configuration.registry import Registry
from mmcsplat.storage.atomic import write_json_atomic, write_text_atomic
from mmcsplat.studies.cells import COMPLETE, CellOutcome
from mmcsplat.studies.spec import Cell, Study, accepted_parameters

#: "Model no more than a scene needs": the smallest variant whose held-out PSNR is this close to the best.
SMALLEST_WITHIN_DB = 0.5
#: Aggregated per variant (mean, std over its complete cells).
METRICS = ("val_masked_psnr", "train_masked_psnr", "val_interior_masked_psnr", "val_psnr", "val_ssim", "train_psnr", "num_gaussians", "floater_share", "iterations",
           "wall_s", "iterations_per_s", "track_wall_s", "track_wall_s_per_frame", "tracking_median_mm", "tracking_p90_mm",
           "landmark_median_mm", "landmark_moving_median_mm", "landmark_still_moving_median_mm", "joint_angle_median_error_deg",
           "joint_angle_p90_error_deg", "knee_flexion_range_deg", "elbow_flexion_range_deg", "hip_flexion_range_deg", "shoulder_flexion_range_deg")
SERIES = ("per_frame_val_masked_psnr", "tracking_per_frame_median_mm")
#: Lists and maps (the series, the fit's warnings, per-camera mask agreement): in results.json, not results.csv.
NESTED = (*SERIES, "warnings", "mask_agreement")
#: Initializers whose presence the reference study's columns report.
MASK_INITIALIZER, SPARSE_INITIALIZER = "masked", "sparsity-pruned"


@attrs.frozen
class Columns:
    """The reference study's description of a configuration: masked targets, the segmentation loss
    weight, sparsity pruning, and the count and extent (cube side, 2 × half_size) of the initial points;
    plus the plugins chosen."""

    mask: bool
    lambda_seg: float
    sparse: bool
    init_points: int | None
    init_range_m: float | None
    initializers: str
    densifier: str | None
    dynamics: str | None


def derive_columns(config: Config, registry: Registry) -> Columns:
    """Read :class:`Columns` off a resolved configuration; the plugins' own defaults fill what it omits."""
    from mmcsplat.training.settings import FitSettings

    initializers = config.plugins("initializer")
    placing = None
    for choice in initializers:
        params = {**accepted_parameters("initializer", choice.name, registry), **choice.params}
        if "num_points" in params:
            placing = params
            break
    half_size = placing.get("half_size") if placing else None
    densifiers, dynamics = config.plugins("densifier"), config.plugins("dynamics")
    return Columns(
        mask=any(choice.name == MASK_INITIALIZER for choice in initializers),
        lambda_seg=float(FitSettings.from_config(config).lambda_seg),
        sparse=any(choice.name == SPARSE_INITIALIZER for choice in initializers),
        init_points=int(placing["num_points"]) if placing else None,
        init_range_m=2.0 * float(half_size) if isinstance(half_size, (int, float)) else None,
        initializers="+".join(choice.name for choice in initializers),
        densifier=densifiers[0].name if densifiers else None,
        dynamics=dynamics[0].name if dynamics else None,
    )


@attrs.frozen
class Row:
    """One cell of the study with its columns and outcome."""

    cell: Cell
    columns: Columns
    outcome: CellOutcome

    def record(self) -> dict[str, Any]:
        cell = self.cell
        return {"variant": cell.variant, "session": cell.session, "fold": cell.fold, "seed": cell.seed, "backend": cell.backend,
                "key": cell.spec.key, **attrs.asdict(self.columns), **{k: v for k, v in attrs.asdict(self.outcome).items() if k != "key"}}


@attrs.frozen
class Aggregate:
    """One variant on one session and backend, over its folds and seeds: mean and standard deviation
    (population) of each metric over the complete cells, the per-frame series averaged frame by frame, and
    the predictions its tracked cells ran with (their ``track_prediction``s, sorted, comma-separated)."""

    label: str
    variant: str
    session: str
    backend: str
    columns: Columns
    cells: int
    failed: int
    mean: Mapping[str, float | None]
    std: Mapping[str, float | None]
    series: Mapping[str, list[float | None]]
    prediction: str | None = None

    def record(self) -> dict[str, Any]:
        return {"label": self.label, "variant": self.variant, "session": self.session, "backend": self.backend,
                "cells": self.cells, "failed": self.failed, **attrs.asdict(self.columns), "prediction": self.prediction,
                **{key: self.mean[key] for key in METRICS}, **{f"{key}_std": self.std[key] for key in METRICS},
                **{key: self.series.get(key) for key in SERIES}}


@attrs.frozen
class Findings:
    """What the study found: the best variant by held-out masked PSNR, the smallest one within
    :data:`SMALLEST_WITHIN_DB` of it, and the Pareto fronts (labels) of wall time and of iterations per
    second against held-out masked PSNR."""

    best: str | None
    smallest_within: str | None
    pareto_wall: list[str]
    pareto_speed: list[str]


def build_rows(cells: Sequence[Cell], outcomes: Mapping[str, CellOutcome], registry: Registry) -> list[Row]:
    """The study's rows, in cell order."""
    columns: dict[str, Columns] = {}
    rows = []
    for cell in cells:
        key = cell.spec.key
        if key not in columns:
            columns[key] = derive_columns(cell.spec.config, registry)
        rows.append(Row(cell, columns[key], outcomes[key]))
    return rows


def aggregate(rows: Sequence[Row], several_sessions: bool, several_backends: bool) -> list[Aggregate]:
    """Aggregates per (variant, session, backend), in the order they first appear."""
    groups: dict[tuple[str, str, str], list[Row]] = {}
    for row in rows:
        groups.setdefault((row.cell.variant, row.cell.session, row.cell.backend), []).append(row)
    result = []
    for (variant, session, backend), members in groups.items():
        done = [row.outcome for row in members if row.outcome.status == COMPLETE]
        mean, std = {}, {}
        for key in METRICS:
            values = [getattr(outcome, key) for outcome in done if getattr(outcome, key) is not None]
            mean[key] = float(np.mean(values)) if values else None
            std[key] = float(np.std(values)) if values else None
        series = {key: _mean_series([getattr(outcome, key) for outcome in done]) for key in SERIES}
        predictions = sorted({outcome.track_prediction for outcome in done if outcome.track_prediction})
        result.append(Aggregate(group_label(variant, session, backend, several_sessions, several_backends), variant, session, backend, members[0].columns, len(members), len(members) - len(done),
                                mean, std, {key: value for key, value in series.items() if value}, ", ".join(predictions) or None))
    return result


def group_label(variant: str, session: str, backend: str, several_sessions: bool, several_backends: bool) -> str:
    """How tables name a variant's group: ``variant @ session [backend]``, each part only when the study
    has several."""
    return variant + (f" @ {session}" if several_sessions else "") + (f" [{backend}]" if several_backends else "")


def _mean_series(series: Iterable[list[float | None] | None]) -> list[float | None]:
    """Frame-by-frame mean of per-frame series (frames missing from some, or ``None`` there, skipped)."""
    present = [s for s in series if s]
    if not present:
        return []
    length = max(len(s) for s in present)
    means = []
    for k in range(length):
        values = [s[k] for s in present if k < len(s) and s[k] is not None]
        means.append(float(np.mean(values)) if values else None)
    return means


def pareto_front(points: Sequence[tuple[float, float]], minimize_x: bool) -> list[int]:
    """Indices of the points no other point beats: higher y, and lower x (``minimize_x``) or higher x;
    sorted by x."""
    def dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
        better_x = a[0] <= b[0] if minimize_x else a[0] >= b[0]
        strictly = (a[0] != b[0]) or (a[1] != b[1])
        return better_x and a[1] >= b[1] and strictly
    front = [i for i, p in enumerate(points) if not any(dominates(q, p) for j, q in enumerate(points) if j != i)]
    return sorted(front, key=lambda i: points[i][0])


def find(aggregates: Sequence[Aggregate]) -> Findings:
    """The study's :class:`Findings` over the aggregates that measured a held-out masked PSNR."""
    scored = [a for a in aggregates if a.mean["val_masked_psnr"] is not None]
    if not scored:
        return Findings(None, None, [], [])
    best = max(scored, key=lambda a: a.mean["val_masked_psnr"])
    close = [a for a in scored if a.mean["val_masked_psnr"] >= best.mean["val_masked_psnr"] - SMALLEST_WITHIN_DB
             and a.mean["num_gaussians"] is not None]
    smallest = min(close, key=lambda a: a.mean["num_gaussians"]) if close else None
    fronts = []
    for key, minimize in (("wall_s", True), ("iterations_per_s", False)):
        usable = [a for a in scored if a.mean[key] is not None]
        fronts.append([usable[i].label for i in pareto_front([(a.mean[key], a.mean["val_masked_psnr"]) for a in usable], minimize)])
    return Findings(best.label, smallest.label if smallest else None, *fronts)


# --------------------------------------------------------------------------------------------- files


def write_tables(out: Path, study: Study, rows: Sequence[Row], aggregates: Sequence[Aggregate], findings: Findings) -> None:
    """OUT/results.json and OUT/results.csv."""
    write_json_atomic(out / "results.json", {
        "study": study.name,
        "source": study.source,
        "description": study.description,
        "findings": attrs.asdict(findings),
        "variants": [a.record() for a in aggregates],
        "cells": [row.record() for row in rows],
    })
    cell_records = [{"row": "cell", **{k: v for k, v in row.record().items() if k not in NESTED}} for row in rows]
    variant_records = [{"row": "variant", **{k: v for k, v in a.record().items() if k not in NESTED}} for a in aggregates]
    fields = list(dict.fromkeys(key for record in cell_records + variant_records for key in record))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    writer.writerows(cell_records + variant_records)
    write_text_atomic(out / "results.csv", buffer.getvalue())


def markdown(study: Study, rows: Sequence[Row], aggregates: Sequence[Aggregate], findings: Findings,
             charts: Sequence[tuple[str, str]], heading: str = "#") -> str:
    """The study's markdown: the variant table, the findings, the charts (``(title, relative path)``),
    the dynamics table when any cell tracked, and the failed cells with their errors."""
    done = sum(row.outcome.status == COMPLETE for row in rows)
    cells = {row.cell.spec.key for row in rows}
    lines = [f"{heading} Study: {study.name}", ""]
    if study.description:
        lines += [study.description, ""]
    folds = sorted({row.cell.fold for row in rows})
    lines += [f"{len(rows)} cells ({len(cells)} distinct runs; {done} complete, {len(rows) - done} failed) over "
              f"session(s) {', '.join(s.name for s in study.sessions)}, folds {', '.join(folds)}, seeds "
              f"{', '.join(map(str, study.seeds))}. PSNR in dB inside the subject mask (interior: the mask less its 1-pixel "
              "edge, whose pixels mix in the background: a masked fit over black cannot model them, one over clean plates can), "
              "mean ± std over folds and seeds.", ""]
    header = ["Variant", "Mask", "λ_seg", "Sparse", "#init points", "init range (m)", "val PSNR", "train PSNR",
              "val PSNR, interior", "wall time (s)", "it/s", "Gaussians", "backend", "cells"]
    table = [header, ["---"] * len(header)]
    for a in aggregates:
        c = a.columns
        table.append([a.label, _yes(c.mask), format_value(c.lambda_seg, "g"), _yes(c.sparse), format_value(c.init_points, ",.0f"),
                      format_value(c.init_range_m, "g"), _spread(a, "val_masked_psnr", ".2f"), _spread(a, "train_masked_psnr", ".2f"),
                      _spread(a, "val_interior_masked_psnr", ".2f"), _spread(a, "wall_s", ".1f"), _spread(a, "iterations_per_s", ".2f"), _spread(a, "num_gaussians", ",.0f"),
                      a.backend, f"{a.cells - a.failed}/{a.cells}"])
    lines += markdown_rows(table) + [""]
    if findings.best:
        lines += [f"- Best held-out masked PSNR: **{findings.best}**.",
                  f"- Smallest model within {SMALLEST_WITHIN_DB} dB of the best (a model no more than the scene needs): "
                  f"**{findings.smallest_within}**.",
                  f"- Pareto front, wall time against held-out masked PSNR: {', '.join(findings.pareto_wall)}.",
                  f"- Pareto front, iterations per second against held-out masked PSNR: {', '.join(findings.pareto_speed)}.", ""]
    tracked = [a for a in aggregates if a.columns.dynamics]
    if tracked:
        table = [["Variant", "dynamics", "prediction", "tracking median (mm)", "tracking p90 (mm)", "joints, median (mm)", "joints that moved > 1 cm (mm)",
                  "… held still (mm)", "joint angles, median error (°)", "tracking (s/frame)", "cells"]]
        table.append(["---"] * len(table[0]))
        for a in tracked:
            table.append([a.label, a.columns.dynamics or "", a.prediction or "—", _spread(a, "tracking_median_mm", ".1f"), _spread(a, "tracking_p90_mm", ".1f"),
                          _spread(a, "landmark_median_mm", ".1f"), _spread(a, "landmark_moving_median_mm", ".1f"),
                          _spread(a, "landmark_still_moving_median_mm", ".1f"), _spread(a, "joint_angle_median_error_deg", ".1f"),
                          _spread(a, "track_wall_s_per_frame", ".2f"),
                          f"{a.cells - a.failed}/{a.cells}"])
        lines += [f"{heading}# Dynamics", ""] + markdown_rows(table) + [""]
    for title, path in charts:
        lines += [f"![{title}]({path})", ""]
    failed = [row for row in rows if row.outcome.status != COMPLETE]
    if failed:
        lines += [f"{heading}# Failed cells", ""]
        lines += [f"- {row.cell.variant}, {row.cell.session}, fold {row.cell.fold}, seed {row.cell.seed} "
                  f"(`cells/{row.cell.spec.key}`), {row.outcome.status}: {row.outcome.error}" for row in failed] + [""]
    return "\n".join(lines)


def markdown_rows(rows: Sequence[Sequence[str]]) -> list[str]:
    """Markdown table lines, one per row (the first row the header, the second the ``---`` rule), with
    ``|`` escaped inside cells."""
    return ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |" for row in rows]


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def format_value(value: float | None, spec: str) -> str:
    """``value`` formatted with ``spec``, or ``—`` for a missing or NaN value."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return format(value, spec)


def _spread(a: Aggregate, key: str, spec: str) -> str:
    """``mean ± std`` of a metric (the mean alone from a single cell)."""
    mean, std = a.mean[key], a.std[key]
    if mean is None:
        return "—"
    return format_value(mean, spec) + (f" ± {format_value(std, spec)}" if a.cells - a.failed > 1 and std is not None else "")
