"""``mmcsplat export RUN --trc / --csv / --c3d``: a run's carried landmarks (``RUN/landmarks.csv``) in the
files biomechanics tools read — TRC for OpenSim and Pose2Sim (Y-up, Pose2Sim's axes), CSV for everyone,
C3D for motion-capture labs (:mod:`mmcsplat.storage.landmark_formats` has each format's conventions)."""

from __future__ import annotations

import json
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import InputError, MissingFileError, OutputExistsError
from mmcsplat.storage.landmark_formats import CSV_INCOMPLETE_COLUMN, read_landmark_csv, write_c3d, write_landmark_csv, write_trc
from mmcsplat.storage.opencap_session import trc_convention
from mmcsplat.storage.run import LANDMARKS_CSV, LANDMARKS_INFO

#: Where and with what each format's files begin (a C3D's second byte is 0x50, its first a block number):
#: an existing file is replaced only when it is of the kind exported.
SIGNATURES = {"trc": (0, b"PathFileType"), "csv": (0, b"frame,time,name,"), "c3d": (1, b"\x50")}


def require_replaceable(path: Path, kind: str) -> None:
    """Refuse to replace an existing file at ``path`` unless it is a ``kind`` file (a landmarks export run
    again): a user's notes named like the output are never overwritten."""
    if not path.is_file() or path.stat().st_size == 0:
        return
    offset, signature = SIGNATURES[kind]
    with open(path, "rb") as handle:
        start = handle.read(offset + len(signature))
    if start[offset:] != signature:
        raise OutputExistsError(f"{path} exists and is not a {kind.upper()} file: export replaces only its own kind of file — "
                                "move it or name another")


def carried_unfinished(run: str | Path) -> list[str]:
    """What was unfinished when the landmarks of ``run`` were carried (RUN/landmarks.json's ``unfinished``):
    landmarks carried with ``--allow-incomplete`` stay incomplete after the run is finished."""
    path = Path(run) / LANDMARKS_INFO
    try:
        record = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise InputError(f"{path} is not readable JSON ({error}): run `mmcsplat landmarks {run}` again") from None
    if not isinstance(record, dict) or not record.get("incomplete"):
        return []
    return [f"its landmarks were carried before it was finished ({problem})" for problem in record.get("unfinished", [])] or [
        f"its landmarks were carried before it was finished: run `mmcsplat landmarks {run}` again"]


def export_landmarks(run: str | Path, trc: str | Path | None = None, csv: str | Path | None = None, c3d: str | Path | None = None,
                     unfinished: Sequence[str] = ()) -> list[Path]:
    """Write the landmarks of ``run`` to each file given; returns the paths written. What is ``unfinished``
    in the run (:func:`~mmcsplat.storage.completeness.require_finished`), else what was when its landmarks
    were carried (:func:`carried_unfinished`, with a warning), labels every file
    (:mod:`mmcsplat.storage.landmark_formats`: a TRC header key, a CSV column, a C3D parameter)."""
    source = Path(run) / LANDMARKS_CSV
    if not source.is_file():
        raise MissingFileError(f"{source} does not exist: `mmcsplat landmarks {run} --source …` carries landmarks first")
    for kind, path in (("trc", trc), ("csv", csv), ("c3d", c3d)):
        if path is not None:
            require_replaceable(Path(path), kind)
    names, frames, times, positions, extra = read_landmark_csv(source)
    problems = list(unfinished) or carried_unfinished(run)
    if problems and not unfinished:
        warnings.warn(f"{source} was carried before run {run} was finished: its exports are labelled incomplete; run `mmcsplat landmarks` "
                      "again for finished ones", stacklevel=2)
    incomplete = f"incomplete run {run}: {'; '.join(problems)}" if problems else None
    if incomplete:
        extra = {**extra, CSV_INCOMPLETE_COLUMN: np.ones(positions.shape[:2])}
    session = RunStates(run).session
    session.session_frames(frames, str(source))  # refuses rows of frames this run's session never took
    written = []
    if trc is not None:
        write_trc(trc, names, times, positions, session.fps, convention=trc_convention(session), incomplete=incomplete,
                  first_frame=int(frames[0]) if len(frames) else 0)
        written.append(Path(trc))
    if csv is not None:
        write_landmark_csv(csv, names, frames, times, positions, extra=extra)
        written.append(Path(csv))
    if c3d is not None:
        write_c3d(c3d, names, times, positions, session.fps, incomplete=incomplete)
        written.append(Path(c3d))
    return written
