"""2D keypoints in DeepLabCut's CSV, as DeepLabCut writes them for anipose (``pose-2d``), triangulated in
the session's cameras.

Layout: one CSV per camera in ``folder`` (``vid-camA.csv``; matched to the session's cameras by name like
videos, or by ``camera_map``). Each file has DeepLabCut's three header rows — ``scorer``, ``bodyparts``,
``coords`` (``x, y, likelihood`` per body part) — then one row per frame of the video, its first cell
the frame number. Multi-animal files (an ``individuals`` row) are read for their first individual.
Likelihoods below ``min_confidence`` count as undetected. DeepLabCut's HDF5 files hold the same table:
save CSV alongside (its ``save_as_csv``), as this machine reads no HDF5 without pandas' PyTables.

The detections are mapped into the stored images and triangulated by :mod:`.triangulation`.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import between, parameter
from mmcsplat.storage.camera_names import match_cameras
from mmcsplat.storage.session import SessionReader

from .triangulation import TriangulatedKeypoints, recorded_cameras, to_session_pixels


def read_deeplabcut_csv(path: Path) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(body part names, frame numbers [T], table [T, L, 3] of x, y, likelihood; NaN where empty)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.reader(handle))
    except OSError as error:
        raise InputError(f"{path}: cannot be read ({error})") from None
    header = {row[0].strip().lower(): index for index, row in enumerate(rows[:4])
              if row and row[0].strip().lower() in ("scorer", "individuals", "bodyparts", "coords")}
    if not {"scorer", "bodyparts", "coords"} <= set(header):
        raise InputError(f"{path}: not a DeepLabCut CSV (it needs the header rows scorer, bodyparts and coords)")
    parts, coords = rows[header["bodyparts"]][1:], rows[header["coords"]][1:]
    columns = range(len(coords))
    if "individuals" in header:  # multi-animal: the first individual's columns
        individuals = rows[header["individuals"]][1:]
        columns = [c for c in columns if individuals[c] == individuals[0]]
    names = tuple(dict.fromkeys(parts[c] for c in columns))
    index = {(parts[c], coords[c]): c for c in columns}
    missing = [(name, coord) for name in names for coord in ("x", "y", "likelihood") if (name, coord) not in index]
    if missing:
        raise InputError(f"{path}: body part {missing[0][0]!r} lacks its {missing[0][1]!r} column")
    body = rows[max(header.values()) + 1 :]
    frames, table = [], np.full((len(body), len(names), 3), np.nan)
    for k, row in enumerate(body):
        try:
            frames.append(int(float(row[0])))
            for j, name in enumerate(names):
                for d, coord in enumerate(("x", "y", "likelihood")):
                    cell = row[1 + index[(name, coord)]]
                    table[k, j, d] = float(cell) if cell.strip() else np.nan
        except (ValueError, IndexError):
            raise InputError(f"{path}: line {max(header.values()) + 2 + k} is not a row of numbers for every column") from None
    return names, np.asarray(frames, dtype=np.int64), table


@attrs.frozen
class DeepLabCutKeypoints(TriangulatedKeypoints):
    """DeepLabCut CSV keypoints per camera, triangulated (module docstring)."""

    folder: str = parameter(doc="the folder of one DeepLabCut CSV per camera (anipose: pose-2d)", kw_only=True)
    min_confidence: float = parameter(0.6, doc="detections of lower likelihood are not used (anipose's default score threshold)",
                                      validator=between(0, 1))
    camera_map: dict | None = parameter(None, doc="session camera name → its CSV file's stem, where the names differ")

    @property
    def described(self) -> str:
        return f"DeepLabCut keypoints {self.folder}"

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """Every camera's detections at ``frames``, in the stored images' pixels (likelihood as confidence)."""
        folder = Path(self.folder)
        if not folder.is_dir():
            raise MissingFileError(f"deeplabcut keypoints: folder {folder} does not exist")
        cameras = [session.camera(name) for name in session.camera_names]
        files = match_cameras(cameras, sorted(folder.glob("*.csv")), "keypoint file", folder, self.camera_map)
        recorded = recorded_cameras(session)
        capture = session.capture_frames(frames)
        result, names = [], None
        for camera in cameras:
            parts, numbers, table = read_deeplabcut_csv(files[camera.name])
            if names is not None and parts != names:
                raise InputError(f"{files[camera.name]}: body parts {list(parts)} differ from the other cameras' {list(names)}")
            names = parts
            rows = {int(number): k for k, number in enumerate(numbers)}
            pixels = np.zeros((len(frames), len(parts), 2))
            confidence = np.zeros((len(frames), len(parts)))
            for k, number in enumerate(capture):
                if int(number) in rows:
                    found = table[rows[int(number)]]
                    known = np.all(np.isfinite(found), axis=1)
                    pixels[k, known], confidence[k, known] = found[known, :2], found[known, 2]
            if camera.name in recorded:
                pixels = to_session_pixels(pixels, recorded[camera.name], camera)
            confidence[confidence < self.min_confidence] = 0.0
            result.append(KeypointObservations(camera.name, parts, frames, pixels, confidence))
        return result
