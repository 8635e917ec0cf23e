"""Landmarks from files of 3D points: ``trc`` (OpenSim / Pose2Sim marker trajectories) and ``csv``
(``frame,time,name,x,y,z`` rows, or ``name,x,y,z`` for one frame), read by
:mod:`mmcsplat.storage.landmark_formats`.

A TRC file's rows are the capture's frames in order from its first row's (``TrcData.first_frame``: frame 0,
or where a trimmed Pose2Sim trial starts); session frames map to them through the session's capture frame
numbers, so an ingest of ``--frames 10:50:2`` still meets the right rows. A DataRate that is the capture's
divided by a whole number k holds every k-th frame (``export --trc`` of a session that took every other frame
writes half the capture's rate); any other (a marker system's own, 100 Hz beside 60 fps video) is said, since its
rows are then not the frames. A CSV's ``frame`` column holds capture frame numbers the same way; frames asked for that a file
lacks are NaN, and said; the one-frame form applies to the run's fitted frame, whichever it is.
"""

from __future__ import annotations

import csv
import warnings
from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.interfaces import Landmarks, LandmarkSource
from mmcsplat.plugin_api.parameters import non_empty, one_of, parameter
from mmcsplat.storage.calibration import metres_per_unit
from mmcsplat.storage.landmark_formats import CSV_SHORT_COLUMNS, TRC_CONVENTIONS, read_landmark_csv, read_trc
from mmcsplat.storage.opencap_session import trc_convention
from mmcsplat.storage.session import SessionReader

#: How far a TRC's DataRate may be from the session's frame rate, relative, before it is said (a phone's
#: 59.94 or 59.98 fps against a file's 60 is the same rate).
RATE_TOLERANCE = 0.01
#: The TRC source's convention that lets the session decide (:meth:`TrcLandmarks.resolved_convention`).
AUTO_CONVENTION = "auto"


def _rows_at(table_frames: np.ndarray, positions: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """[len(wanted), L, 3] rows of ``positions`` whose frame numbers are ``wanted`` (NaN where none is)."""
    result = np.full((len(wanted), positions.shape[1], 3), np.nan)
    index = {int(frame): k for k, frame in enumerate(table_frames)}
    for k, frame in enumerate(wanted):
        if int(frame) in index:
            result[k] = positions[index[int(frame)]]
    return result


def _say_uncovered(what: str, held: np.ndarray, wanted: np.ndarray, note: str = "") -> None:
    """Warn when the capture frames ``wanted`` are not all among the file's ``held`` ones (sorted): they are NaN."""
    outside = wanted[~np.isin(wanted, held)]
    if len(outside) and len(held):
        warnings.warn(f"{what}: its rows are the capture's frames {held[0]}–{held[-1]}{note}; {len(outside)} of the {len(wanted)} frames "
                      f"asked for ({outside[0]}…{outside[-1]}) have no landmarks there", stacklevel=3)


@attrs.frozen
class TrcLandmarks(LandmarkSource):
    """Marker trajectories of a TRC file (units from its header)."""

    path: str = parameter(doc="the .trc file", validator=non_empty, kw_only=True)
    convention: str = parameter(AUTO_CONVENTION, doc="axes: pose2sim (Y-up: a point is (Z, X, Y) in the calibration's frame), none (as "
                                "written), opencap-ground, opencap-wall, opencap-wall-inverted (OpenCap's, by its board's placement), or "
                                "auto: OpenCap's for a session calibrated by OpenCap, else pose2sim", validator=one_of(AUTO_CONVENTION, *TRC_CONVENTIONS))

    def read(self, session: SessionReader, frames: Sequence[int]) -> Landmarks:
        data = read_trc(self.path, self.resolved_convention(session))
        ratio = session.capture_fps / data.rate
        step = max(1, round(ratio))  # the file holds every step-th frame of the capture
        if abs(ratio - step) > RATE_TOLERANCE * ratio:
            warnings.warn(f"TRC {self.path}: DataRate {data.rate:g} Hz, but the capture of session {session.url} is at {session.capture_fps:g} "
                          f"fps; its row k is taken as the capture's frame {'k' if step == 1 else f'{step}·k'}, so if its rows are not the "
                          "video's frames (a marker system's own rate), resample it to them", stacklevel=2)
        wanted = session.capture_frames(frames)
        held = data.first_frame + step * np.arange(len(data.times))  # the capture's frame of each row
        _say_uncovered(f"TRC {self.path}", held, wanted, " (its OrigDataStartFrame)" if data.first_frame else "")
        return Landmarks(data.names, frames, _rows_at(held, data.positions, wanted), source=f"TRC {Path(self.path)}")

    def resolved_convention(self, session: SessionReader) -> str:
        """The convention, ``auto`` resolved by the session (:func:`~mmcsplat.storage.opencap_session.trc_convention`)."""
        return trc_convention(session) if self.convention == AUTO_CONVENTION else self.convention


@attrs.frozen
class CsvLandmarks(LandmarkSource):
    """Landmarks of a CSV file: one frame (``name,x,y,z``) or many (``frame,time,name,x,y,z``)."""

    path: str = parameter(doc="the .csv file", validator=non_empty, kw_only=True)
    units: str = parameter("m", doc="unit of x, y, z: m or mm", validator=one_of("m", "mm"))

    def read(self, session: SessionReader, frames: Sequence[int]) -> Landmarks:
        names, table_frames, _, positions, _ = read_landmark_csv(self.path)
        positions = positions * metres_per_unit(self.units)
        with open(self.path, encoding="utf-8-sig") as handle:
            one_frame = tuple(next(csv.reader(handle), []))[: len(CSV_SHORT_COLUMNS)] == CSV_SHORT_COLUMNS
        if one_frame:  # no frame column: the landmarks of the fitted frame (the first asked for)
            at = np.full((len(frames), len(names), 3), np.nan)
            at[0] = positions[0]
            return Landmarks(names, frames, at, source=f"CSV {Path(self.path)} (one frame)")
        wanted = session.capture_frames(frames)
        _say_uncovered(f"CSV {self.path}", np.unique(table_frames), wanted)
        return Landmarks(names, frames, _rows_at(table_frames, positions, wanted), source=f"CSV {Path(self.path)}")
