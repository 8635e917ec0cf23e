"""Stability of a study's variants: each run over N seeds, every cell classified, failure rates per variant.

A stability run is the study (:mod:`mmcsplat.studies.spec`) with its seeds replaced by ``0 … N-1``, run by the
same runner into the same cells (a compare run in the same directory shares them). Every cell is then
classified:

- **diverged**: the fit stopped on a NaN/Inf (status ``diverged``), a metric came out NaN/Inf, or the loss
  blew up — its final value above :data:`BLOWUP_FACTOR` × its lowest (when the fit records both);
- **failed**: any other error (the subject in no training view, a calibration the fit cannot use …);
- **floaters**: more than :data:`FLOATER_THRESHOLD` of the fitted opacity mass lies outside the visual hull
  of the session's masks (``floater_share`` of ``mmcsplat evaluate``);
- **calibration**: a camera's mask disagrees with the other cameras' — less than
  :data:`AGREEMENT_THRESHOLD` of it lies on their visual hull (``mask_agreement`` of ``mmcsplat
  evaluate``): its extrinsics (or its mask) are wrong;
- **overfit**: the training views' masked PSNR exceeds the held-out view's by more than :data:`GAP_DB`: the
  fit reproduces what it saw and not the scene (too few cameras, or a wrong calibration);
- **drift**: the drift detector (:mod:`mmcsplat.analysis.drift`) judged a tracked cell to drift;
- **warned**: the fit warned (fewer than :data:`~mmcsplat.pipeline.fit.MIN_TRAINING_CAMERAS` training cameras see
  the subject, or one never does).

The thresholds were chosen by measurement (docs/studies.md, "Stability").

Per variant (and session and backend): the number of runs, the fraction of each class, and the spread of
the held-out masked PSNR (mean, standard deviation, minimum over the runs that measured one).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import write_json_atomic, write_text_atomic
from mmcsplat.studies.cells import DIVERGED, FAILED, CellOutcome
from mmcsplat.studies.results import Row, format_value, group_label, markdown_rows
from mmcsplat.studies.runner import StudyRun, run_study
from mmcsplat.studies.spec import Study

DEFAULT_SEEDS = 5
#: A loss ending above this multiple of its lowest value blew up (block means of the fit: run.json's
#: ``loss_final`` and ``loss_min``).
BLOWUP_FACTOR = 10.0
#: Floaters: more than this share of the opacity mass outside the masks' visual hull.
FLOATER_THRESHOLD = 0.10
#: Calibration: a camera with less than this share of its mask on the other cameras' visual hull. On the
#: synthetic capture consistent cameras score 0.998–1 and the others beside a wrong one 0.90 or more; one
#: camera turned by 5° scores 0.74–0.93, by 10° 0.43–0.86.
AGREEMENT_THRESHOLD = 0.85
#: Overfit: the training views' masked PSNR above the held-out view's by more than this many dB. On the
#: synthetic capture 3 to 7 training cameras leave 1.5–5.3 dB, 2 cameras or a camera 10° off 10–12 dB.
GAP_DB = 8.0
#: The classes of a cell, in table order.
CLASSES = ("diverged", "failed", "floaters", "calibration", "overfit", "drift", "warned")


@attrs.frozen
class Verdict:
    """One cell's classes (a subset of :data:`CLASSES`) and why, one reason per class."""

    classes: tuple[str, ...]
    reasons: tuple[str, ...]


def classify(outcome: CellOutcome) -> Verdict:
    """The :class:`Verdict` of one cell (module docstring)."""
    found: dict[str, str] = {}
    if outcome.status == DIVERGED:
        found["diverged"] = outcome.error or "diverged"
    elif outcome.status == FAILED:
        found["failed"] = outcome.error or "failed"
    else:
        bad = [key for key in ("val_masked_psnr", "val_psnr", "train_masked_psnr", "train_psnr", "floater_share")
               if isinstance(getattr(outcome, key), float) and not math.isfinite(getattr(outcome, key))]
        if bad:
            found["diverged"] = f"non-finite {', '.join(bad)}"
        elif outcome.loss_min is not None and outcome.loss_final is not None and outcome.loss_final > BLOWUP_FACTOR * outcome.loss_min:
            found["diverged"] = f"loss blew up: final {outcome.loss_final:.4g} > {BLOWUP_FACTOR:g} × lowest {outcome.loss_min:.4g}"
        if outcome.floater_share is not None and outcome.floater_share > FLOATER_THRESHOLD:
            found["floaters"] = f"{outcome.floater_share:.0%} of the opacity mass outside the visual hull"
        disagreeing = sorted((score, name) for name, score in (outcome.mask_agreement or {}).items() if score < AGREEMENT_THRESHOLD)
        if disagreeing:
            found["calibration"] = ", ".join(f"camera {name!r}: {score:.0%} of its mask on the other cameras' visual hull" for score, name in disagreeing) \
                + " (wrong extrinsics or mask?)"
        train, held_out = outcome.train_masked_psnr, outcome.val_masked_psnr
        if train is not None and held_out is not None and train - held_out > GAP_DB:
            found["overfit"] = f"training views {train:.1f} dB, held-out {held_out:.1f} dB (masked PSNR): {train - held_out:.1f} dB apart"
        if outcome.drift:
            found["drift"] = "the drift detector flagged the tracks"
        if outcome.warnings:
            found["warned"] = "; ".join(outcome.warnings)
    classes = tuple(name for name in CLASSES if name in found)
    return Verdict(classes, tuple(found[name] for name in classes))


@attrs.frozen
class StabilityRow:
    """One variant on one session and backend over its runs: the fraction of runs in each class, the
    fraction with any class (``unstable``), and held-out masked PSNR mean, std (population) and min."""

    label: str
    variant: str
    session: str
    backend: str
    runs: int
    fractions: dict[str, float]
    unstable: float
    psnr_mean: float | None
    psnr_std: float | None
    psnr_min: float | None
    floater_share_mean: float | None

    def record(self) -> dict[str, Any]:
        """The row as stability.json and stability.csv write it: one column per class."""
        return {"label": self.label, "variant": self.variant, "session": self.session, "backend": self.backend, "runs": self.runs,
                **{name: self.fractions[name] for name in CLASSES}, "unstable": self.unstable,
                "val_masked_psnr_mean": self.psnr_mean, "val_masked_psnr_std": self.psnr_std, "val_masked_psnr_min": self.psnr_min,
                "floater_share_mean": self.floater_share_mean}


@attrs.frozen
class Stability:
    """A stability run: the study run (its rows), every row's verdict, the variant rows, the seeds."""

    run: StudyRun
    verdicts: list[Verdict]
    rows: list[StabilityRow]
    seeds: tuple[int, ...]


def with_seeds(study: Study, count: int) -> Study:
    """``study`` with seeds ``0 … count-1``."""
    if count < 1:
        raise InputError(f"--seeds must be ≥ 1, got {count}")
    return attrs.evolve(study, seeds=tuple(range(count)))


def summarize(rows: Sequence[Row], verdicts: Sequence[Verdict]) -> list[StabilityRow]:
    """Per (variant, session, backend), in order of first appearance: :class:`StabilityRow`."""
    groups: dict[tuple[str, str, str], list[int]] = {}
    for index, row in enumerate(rows):
        groups.setdefault((row.cell.variant, row.cell.session, row.cell.backend), []).append(index)
    several_sessions = len({key[1] for key in groups}) > 1
    several_backends = len({key[2] for key in groups}) > 1
    result = []
    for (variant, session, backend), members in groups.items():
        classes = [verdicts[i].classes for i in members]
        psnrs = [v for i in members if (v := rows[i].outcome.val_masked_psnr) is not None and math.isfinite(v)]
        shares = [v for i in members if (v := rows[i].outcome.floater_share) is not None and math.isfinite(v)]
        result.append(StabilityRow(
            label=group_label(variant, session, backend, several_sessions, several_backends),
            variant=variant, session=session, backend=backend, runs=len(members),
            fractions={name: sum(name in found for found in classes) / len(members) for name in CLASSES},
            unstable=sum(bool(found) for found in classes) / len(members),
            psnr_mean=float(np.mean(psnrs)) if psnrs else None,
            psnr_std=float(np.std(psnrs)) if psnrs else None,
            psnr_min=float(np.min(psnrs)) if psnrs else None,
            floater_share_mean=float(np.mean(shares)) if shares else None,
        ))
    return result


def run_stability(study: Study, out: str | Path, seeds: int = DEFAULT_SEEDS, **runner: Any) -> Stability:
    """Run ``study`` over ``seeds`` seeds in ``out`` (``runner``: :func:`~mmcsplat.studies.runner.run_study`'s
    executor options), classify its cells and write OUT/stability.json, .csv and .md."""
    run = run_study(with_seeds(study, seeds), out, **runner)
    verdicts = [classify(row.outcome) for row in run.rows]
    result = Stability(run, verdicts, summarize(run.rows, verdicts), tuple(range(seeds)))
    write_stability(Path(out), result)
    return result


def write_stability(out: Path, result: Stability) -> None:
    """OUT/stability.json (thresholds, variant rows, cells with their verdicts), stability.csv (the
    variant rows) and stability.md (:func:`stability_markdown`)."""
    from mmcsplat.training.views import MIN_TRAINING_CAMERAS  # torch: not at import, which `mmcsplat --help` does

    cells = [{"variant": row.cell.variant, "session": row.cell.session, "fold": row.cell.fold, "seed": row.cell.seed,
              "backend": row.cell.backend, "key": row.cell.spec.key, "status": row.outcome.status, "error": row.outcome.error,
              "val_masked_psnr": row.outcome.val_masked_psnr, "train_masked_psnr": row.outcome.train_masked_psnr,
              "floater_share": row.outcome.floater_share, "mask_agreement": row.outcome.mask_agreement, "drift": row.outcome.drift,
              "loss_min": row.outcome.loss_min, "loss_final": row.outcome.loss_final,
              "classes": list(verdict.classes), "reasons": list(verdict.reasons)}
             for row, verdict in zip(result.run.rows, result.verdicts)]
    write_json_atomic(out / "stability.json", {
        "study": result.run.study.name,
        "seeds": list(result.seeds),
        "thresholds": {"floater_share": FLOATER_THRESHOLD, "loss_blowup_factor": BLOWUP_FACTOR, "mask_agreement": AGREEMENT_THRESHOLD,
                       "psnr_gap_db": GAP_DB, "min_training_cameras": MIN_TRAINING_CAMERAS},
        "variants": [row.record() for row in result.rows],
        "cells": cells,
    })
    records = [row.record() for row in result.rows]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(records[0]) if records else ["label"], lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    write_text_atomic(out / "stability.csv", buffer.getvalue())
    write_text_atomic(out / "stability.md", stability_markdown(result))


def stability_table(rows: Sequence[StabilityRow]) -> str:
    """The variant rows as a markdown table (fractions in per cent, PSNR in dB)."""
    header = ["Variant", "runs", *CLASSES, "unstable", "val PSNR mean", "std", "min", "floater share"]
    table = [header, ["---"] * len(header)]
    for row in rows:
        table.append([row.label, str(row.runs), *(f"{row.fractions[name]:.0%}" for name in CLASSES), f"{row.unstable:.0%}",
                      format_value(row.psnr_mean, ".2f"), format_value(row.psnr_std, ".2f"), format_value(row.psnr_min, ".2f"),
                      format_value(row.floater_share_mean, ".1%")])
    return "\n".join(markdown_rows(table))


def stability_markdown(result: Stability) -> str:
    """stability.md: the thresholds, the variant table and the flagged cells with their reasons."""
    lines = [f"# Stability: {result.run.study.name}", "",
             f"{len(result.run.rows)} runs over seeds {', '.join(map(str, result.seeds))}. Fractions of runs that diverged "
             f"(NaN/Inf, or a final loss above {BLOWUP_FACTOR:g} × its lowest), failed otherwise, left floaters (more than "
             f"{FLOATER_THRESHOLD:.0%} of the opacity mass outside the masks' visual hull), had a camera out of calibration (less than "
             f"{AGREEMENT_THRESHOLD:.0%} of its mask on the other cameras' visual hull), overfit (training views more than {GAP_DB:g} dB "
             "above the held-out view), drifted (tracked runs) or warned; held-out masked PSNR in dB over the runs that measured one.", "",
             stability_table(result.rows), ""]
    flagged = [(row, verdict) for row, verdict in zip(result.run.rows, result.verdicts) if verdict.classes]
    if flagged:
        lines += ["## Flagged runs", ""]
        lines += [f"- {row.cell.variant}, {row.cell.session}, fold {row.cell.fold}, seed {row.cell.seed} (`cells/{row.cell.spec.key}`): "
                  + "; ".join(f"**{name}**: {reason}" for name, reason in zip(verdict.classes, verdict.reasons)) for row, verdict in flagged]
        lines.append("")
    return "\n".join(lines)
