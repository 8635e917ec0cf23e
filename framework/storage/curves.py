"""``RUN/curves.csv``: the training curves of a run — loss and PSNR per logged step of its first-frame fit
and of its tracking — for the report's plots and for the user's own (any spreadsheet or pandas reads it).

One row per logged step: ``stage`` (``fit`` or ``track``), ``step`` (iterations of that stage so far),
``frame`` (the session frame trained; empty for a method training all frames at once), ``loss`` and ``psnr`` (dB, inside the training masks as the loss
sees them; means over the step's block of views), ``gaussians`` and ``elapsed_s`` (training time of the
stage). Each stage owns its rows: writing a stage replaces its rows and keeps the other's, atomically.
"""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path

import attrs

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import write_text_atomic
from mmcsplat.storage.run import CURVES_FILE

COLUMNS = ("stage", "step", "frame", "loss", "psnr", "gaussians", "elapsed_s")
STAGES = ("fit", "track")


@attrs.define
class TrainingCurve:
    """The rows one stage logs, in step order. Dynamics plugins log through ``TrackingContext.curve``:
    ``curve.log(step=…, frame=…, loss=…, psnr=…)`` once per logged step (e.g. per frame, or per block of
    iterations); the pipeline writes them to ``RUN/curves.csv``."""

    stage: str = attrs.field(validator=attrs.validators.in_(STAGES))
    rows: list[dict] = attrs.field(factory=list)
    started: float = attrs.field(factory=time.perf_counter, eq=False)

    def log(self, *, step: int, frame: int | None, loss: float, psnr: float | None, gaussians: int | None = None,
            elapsed_s: float | None = None) -> None:
        """Record one logged step; ``elapsed_s`` defaults to the time since the curve was made."""
        elapsed = time.perf_counter() - self.started if elapsed_s is None else elapsed_s
        self.rows.append({"stage": self.stage, "step": int(step), "frame": None if frame is None else int(frame), "loss": float(loss),
                          "psnr": None if psnr is None else float(psnr), "gaussians": None if gaussians is None else int(gaussians),
                          "elapsed_s": round(float(elapsed), 3)})

    def write(self, run: str | Path) -> None:
        """Replace this stage's rows of ``run``/curves.csv with :attr:`rows`, keeping the other stage's."""
        rows = [row for row in read_curves(run) if row["stage"] != self.stage] + self.rows
        rows.sort(key=lambda row: STAGES.index(row["stage"]))  # stable: the fit's rows, then the track's
        text = io.StringIO()
        writer = csv.DictWriter(text, COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows({key: _cell(value) for key, value in row.items()} for row in rows)
        write_text_atomic(Path(run) / CURVES_FILE, text.getvalue())


def _cell(value: str | int | float | None) -> str:
    if value is None:
        return ""
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def read_curves(run: str | Path) -> list[dict]:
    """The rows of ``run``/curves.csv as dicts (numbers parsed; empty cells ``None``); [] when there is none.
    A file that is not a curves table is an error naming it."""
    path = Path(run) / CURVES_FILE
    if not path.exists():
        return []
    with open(path, newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        if tuple(reader.fieldnames or ()) != COLUMNS:
            raise InputError(f"{path}: expected the columns {', '.join(COLUMNS)}, got {reader.fieldnames}")
        rows = []
        for number, row in enumerate(reader, start=2):
            try:
                rows.append({
                    "stage": row["stage"],
                    "step": int(row["step"]),
                    "frame": int(row["frame"]) if row["frame"] else None,
                    **{key: float(row[key]) if row[key] else None for key in ("loss", "psnr", "elapsed_s")},
                    "gaussians": int(row["gaussians"]) if row["gaussians"] else None,
                })
            except (TypeError, ValueError) as error:
                raise InputError(f"{path}: line {number} is not a curves row ({error})") from None
    return rows
