"""2D keypoints in DeepLabCut's CSV or HDF5 files, as DeepLabCut writes them for anipose (``pose-2d``),
triangulated in the session's cameras.

Layout: one file per camera in ``folder`` (``vid-camA.csv`` or ``vid-camA.h5``; the CSVs when the folder
has both), or named by ``files``, matched to the session's cameras by name like videos, or by ``camera_map``. Both hold one table:
a column per (scorer, body part, coordinate) — ``x, y, likelihood`` per body part, with an
``individuals`` level between scorer and body part in multi-animal files — and a row per frame of the
video, indexed by the frame number. Likelihoods below ``min_confidence`` count as undetected.

Multi-animal files: every individual whose body parts are the animals' (the set most individuals share;
DeepLabCut's ``single``, which holds the project's unique body parts, is no animal) is a candidate, and the
subject is the animal the cameras agree on (:mod:`.keypoint_tables`); ``individual`` names one instead, for
files whose identities are the same animal in every camera.

- CSV: the column levels are the first header rows (``scorer``, [``individuals``,] ``bodyparts``,
  ``coords``), then one row per frame, its first cell the frame number.
- HDF5: pandas' ``table`` format (``DataFrame.to_hdf(key="df_with_missing", format="table")``), read with
  h5py, without pandas or PyTables: the group ``df_with_missing`` (or the file's only group) holds the
  dataset ``table`` of records (``index``: the frame number; ``values_block_0``: the row's values), and
  the group's attribute ``non_index_axes`` the column labels, as PyTables stores a Python object — a
  pickle, read here by an unpickler that builds lists, tuples and strings only (a file asking for
  anything else is refused, never run).

The files declare no skeleton (a mask drawn from them is the points' hull, ``segmenters/keypoints.py``).
The detections are mapped into the stored images and triangulated by :mod:`.triangulation`.
"""

from __future__ import annotations

import csv
import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.parameters import between, parameter
from mmcsplat.storage.plain_pickle import load_plain

from .keypoint_tables import KeypointTable, TableKeypoints

COORDS = ("x", "y", "likelihood")
#: The key DeepLabCut writes its table under.
HDF_KEY = "df_with_missing"


def keypoint_table(path: Path, columns: Sequence[tuple[str, ...]], frames: Sequence[int], values: np.ndarray,
                   individual: str | None = None) -> KeypointTable:
    """(body parts, frame numbers, [T, P, L, 3] x, y, likelihood of P individuals) of a DeepLabCut table whose
    columns are (scorer, [individual,] body part, coordinate) labels and ``values`` [T, columns]: every animal
    (module docstring), or ``individual`` alone."""
    if not columns or any(len(label) != len(columns[0]) or len(label) not in (3, 4) for label in columns):
        raise InputError(f"{path}: not a DeepLabCut table (its columns need the levels scorer, [individuals,] bodyparts and coords)")
    owners = [label[1] if len(label) == 4 else "" for label in columns]
    parts = {owner: tuple(dict.fromkeys(label[-2] for label, o in zip(columns, owners, strict=True) if o == owner)) for owner in dict.fromkeys(owners)}
    names = max(parts.values(), key=list(parts.values()).count)
    animals = [owner for owner, owned in parts.items() if owned == names]
    if individual is not None:
        if individual not in animals:
            found = f"its individuals are {', '.join(animals)}" if animals != [""] else "it is a single-animal table"
            raise InputError(f"{path}: no individual {individual!r} ({found})")
        animals = [individual]
    index = {(owner, label[-2], label[-1]): c for c, (label, owner) in enumerate(zip(columns, owners, strict=True))}
    missing = [(owner, name, coord) for owner in animals for name in names for coord in COORDS if (owner, name, coord) not in index]
    if missing:
        raise InputError(f"{path}: body part {missing[0][1]!r} {'of ' + repr(missing[0][0]) + ' ' if missing[0][0] else ''}"
                         f"lacks its {missing[0][2]!r} column")
    table = np.stack([values[:, [[index[(owner, name, coord)] for coord in COORDS] for name in names]] for owner in animals], axis=1)
    return names, np.asarray(frames, dtype=np.int64), table.astype(np.float64)


def read_deeplabcut_csv(path: Path, individual: str | None = None) -> KeypointTable:
    """(body part names, frame numbers [T], table [T, P, L, 3] of x, y, likelihood; NaN where empty): see
    :func:`keypoint_table`."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.reader(handle))
    except OSError as error:
        raise InputError(f"{path}: cannot be read ({error})") from None
    levels = ("scorer", "individuals", "bodyparts", "coords")
    header = {row[0].strip().lower(): index for index, row in enumerate(rows[:4]) if row and row[0].strip().lower() in levels}
    if not {"scorer", "bodyparts", "coords"} <= set(header):
        raise InputError(f"{path}: not a DeepLabCut CSV (it needs the header rows scorer, bodyparts and coords)")
    columns = list(zip(*(rows[header[level]][1:] for level in levels if level in header)))
    body = rows[max(header.values()) + 1 :]
    frames, values = [], np.full((len(body), len(columns)), np.nan)
    for k, row in enumerate(body):
        try:
            frames.append(int(float(row[0])))
            values[k] = [float(cell) if cell.strip() else np.nan for cell in row[1 : 1 + len(columns)]]
        except (ValueError, IndexError):
            raise InputError(f"{path}: line {max(header.values()) + 2 + k} is not a row of numbers for every column") from None
    return keypoint_table(path, columns, frames, values, individual)


def read_deeplabcut_h5(path: Path, individual: str | None = None) -> KeypointTable:
    """A DeepLabCut HDF5 file (pandas' table format) as :func:`read_deeplabcut_csv` reads a CSV."""
    import h5py

    try:
        with h5py.File(path, "r") as file:
            groups = [key for key in file if isinstance(file[key], h5py.Group)]
            key = HDF_KEY if HDF_KEY in groups else groups[0] if len(groups) == 1 else None
            if key is None or "table" not in file[key] or "non_index_axes" not in file[key].attrs:
                raise InputError(f"{path}: not a DeepLabCut HDF5 table (no {HDF_KEY}/table with its column labels); "
                                 "export it from DeepLabCut again, or as CSV")
            records = file[key]["table"][()]
            labels = file[key].attrs["non_index_axes"]
    except OSError as error:
        raise InputError(f"{path}: not a readable HDF5 file ({error})") from None
    try:
        axes = load_plain(labels.tobytes() if isinstance(labels, np.ndarray) else bytes(labels))
        columns = [tuple(str(level) for level in label) for label in dict(axes)[1]]
    except (pickle.UnpicklingError, EOFError, TypeError, ValueError, KeyError) as error:
        raise InputError(f"{path}: its column labels (non_index_axes) are not DeepLabCut's ({error})") from None
    blocks = sorted(name for name in records.dtype.names if name.startswith("values_block_"))
    if "index" not in records.dtype.names or len(blocks) != 1:
        raise InputError(f"{path}: its table has fields {records.dtype.names}, expected index and one values_block_0 of numbers")
    values = np.asarray(records[blocks[0]], dtype=np.float64).reshape(len(records), -1)
    if values.shape[1] != len(columns):
        raise InputError(f"{path}: {values.shape[1]} values a row but {len(columns)} column labels")
    return keypoint_table(path, columns, records["index"], values, individual)


@attrs.frozen
class DeepLabCutKeypoints(TableKeypoints):
    """DeepLabCut CSV or HDF5 keypoints per camera, triangulated (module docstring)."""

    folder: str | None = parameter(None, doc="the folder of one DeepLabCut CSV or HDF5 file per camera (anipose: pose-2d)")
    files: tuple[str, ...] | None = parameter(None, doc="the DeepLabCut files themselves, one per camera (instead of folder)")
    min_confidence: float = parameter(0.6, doc="detections of lower likelihood are not used (anipose's default score threshold)",
                                      validator=between(0, 1))
    individual: str | None = parameter(None, doc="multi-animal files: the individual to read, where it is the same animal in every camera "
                                                 "(default: the animal the cameras agree on)")

    SUFFIXES: ClassVar[tuple[str, ...]] = (".csv", ".h5")

    @property
    def described(self) -> str:
        return f"DeepLabCut keypoints {self.where}"

    def read_table(self, path: Path) -> KeypointTable:
        read = read_deeplabcut_csv if path.suffix.lower() == ".csv" else read_deeplabcut_h5
        return read(path, self.individual)
