"""Landmark trajectories in the files biomechanics tools read and write: TRC, a long-format CSV and C3D.

This module is the one place these formats are parsed and written. In memory a set of trajectories is

* ``names``: ``tuple[str, ...]`` of L landmark names (``"LWrist"``, ``"RAnkle"``, …), unique;
* ``times``: ``[T]`` seconds; ``frames``: ``[T]`` integer frame numbers;
* ``positions``: ``[T, L, 3]`` float64, metres, in mmcsplat's world frame; NaN where a landmark is unknown.

**TRC** (``.trc``): OpenSim's and Pose2Sim's marker-trajectory text file, tab-separated. Line 1
``PathFileType<TAB>4<TAB>(X/Y/Z)<TAB>FILENAME``; line 2 the header keys ``DataRate CameraRate NumFrames
NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames``; line 3 their values; line 4 ``Frame#``,
``Time`` and each marker name followed by two empty cells; line 5 two empty cells then ``X1 Y1 Z1 X2 …``;
then one row per frame: the frame number, the time in seconds and X, Y, Z per marker (an empty cell is a
missing value). Units are ``m`` or ``mm``. Axes: Pose2Sim writes Y up, and in the calibration's world
frame (mmcsplat's) a joint is (trc Z, trc X, trc Y); so with ``convention="pose2sim"`` world = (Z, X, Y)
and the file's (X, Y, Z) = (world y, world z, world x). ``convention="none"`` keeps the axes as they are.
OpenCap writes Y up too, turned from its calibration board's frame (the world of its cameras,
:mod:`.opencap_calibration`) by the board's placement: ``"opencap-ground"`` (a board lying on the floor)
world = (−Z, X, −Y), ``"opencap-wall"`` (a board upright on a wall) world = (−Z, −Y, −X), and
``"opencap-wall-inverted"`` (the same board upside down) world = (Z, Y, −X) (:func:`.opencap_calibration.opencap_convention`
tells them apart from the cameras). OpenCap's first line has a space after ``PathFileType``, not a tab.
Which frame of the capture a TRC's first row is (``TrcData.first_frame``) is told by its writer's habit:
Pose2Sim writes the capture's 0-based frame numbers in ``Frame#``, ``Time`` = frame / rate and the first in
``OrigDataStartFrame`` (a trial it trimmed to where the subject is seen starts later than frame 0; the
versions before wrote ``Frame#`` 1, 2, … and ``OrigDataStartFrame`` 0); OpenCap and OpenSim number from 1
(``OrigDataStartFrame`` 1, ``Time`` 0 at the first row). So an ``OrigDataStartFrame`` of 2 or more is the
first row's frame, 1 is frame 1 where the first row's time is one frame in (Pose2Sim's) and frame 0
otherwise, and 0 or none is frame 0.

**CSV** (``.csv``): long format, one row per frame and landmark, columns ``frame,time,name,x,y,z`` in
metres in mmcsplat's world frame, then any extra numeric columns (``spread_mm``, ``confidence``, …), one
value per frame and landmark. The short form ``name,x,y,z`` (no frame or time) is one frame: frame 0 at
time 0. Empty cells are missing values (NaN).

**C3D** (``.c3d``): the binary motion-capture format of the lab systems (Vicon, Qualisys, …). POINT data
in millimetres (``POINT:UNITS = "mm"``), ``POINT:LABELS`` the names, ``POINT:RATE`` the frame rate, a
residual of 0 for a valid point and -1 for a missing one (C3D's mark of an invalid point). C3D has no fixed
up axis (each lab declares its own), so mmcsplat's world axes are written unchanged.

**Incomplete runs**: landmarks of a run whose fit or tracking was not finished (``--allow-incomplete``)
are labelled in each format where its readers keep reading: in TRC an extra header key ``Incomplete``
(line 2) whose value (line 3) says what is unfinished; in CSV an extra column ``incomplete``, 1 on every
row; in C3D the parameter ``MMCSPLAT:INCOMPLETE`` holding the same text as TRC.

Why two ways: TRC and CSV are small text formats with no maintained Python library for TRC, so both are
read and written here by hand, with errors naming the file and the line at fault. C3D is a binary format
with many variants (processor types, integer or float storage, scale factors, parameter blocks), so it
goes through ezc3d, the maintained C3D library.

Every write is atomic (:mod:`mmcsplat.storage.atomic`): a reader sees the old file or the new one. Every
reading error is an :class:`~mmcsplat.plugin_api.errors.InputError` whose one-line message names the file
(and the line where there is one).
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.storage.atomic import atomic_path, write_text_atomic

#: Axis conventions of TRC files (module docstring): world = AXES[convention] @ trc, a signed permutation,
#: so trc = AXES[convention].T @ world.
TRC_AXES = {
    "pose2sim": np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=np.float64),
    "none": np.eye(3),
    "opencap-ground": np.array([[0, 0, -1], [1, 0, 0], [0, -1, 0]], dtype=np.float64),
    "opencap-wall": np.array([[0, 0, -1], [0, -1, 0], [-1, 0, 0]], dtype=np.float64),
    "opencap-wall-inverted": np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=np.float64),
}
TRC_CONVENTIONS = tuple(TRC_AXES)

#: Length units, in metres.
_UNITS = {"m": 1.0, "mm": 1e-3}
_C3D_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
TRC_HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate", "OrigDataStartFrame", "OrigNumFrames")
CSV_COLUMNS = ("frame", "time", "name", "x", "y", "z")
CSV_SHORT_COLUMNS = ("name", "x", "y", "z")
#: Where an incomplete run's landmarks say so (module docstring): the TRC header key, the CSV column and the
#: C3D parameter (group, name).
TRC_INCOMPLETE_KEY = "Incomplete"
CSV_INCOMPLETE_COLUMN = "incomplete"
C3D_INCOMPLETE_PARAMETER = ("MMCSPLAT", "INCOMPLETE")


@attrs.frozen(eq=False)
class TrcData:
    """A TRC file as read: ``positions`` [T, L, 3] in world metres (the convention applied, NaN where missing),
    ``frame_numbers`` [T] as in the file, ``times`` [T] seconds, ``rate`` the DataRate, ``units`` as read."""

    names: tuple[str, ...]
    frame_numbers: np.ndarray
    times: np.ndarray
    positions: np.ndarray
    rate: float
    units: str
    #: What was unfinished in the run the file was exported from (its ``Incomplete`` header), else ``None``.
    incomplete: str | None = None
    #: The capture's frame of the first row (module docstring), 0-based.
    first_frame: int = 0


def _one_line(text: str) -> str:
    """``text`` with every run of whitespace (tabs, line breaks) one space: a TRC header cell, a C3D string."""
    return " ".join(text.split())


# --- shared checks -------------------------------------------------------------------------------------------


def _check_names(names: Sequence[str], where: str) -> tuple[str, ...]:
    names = tuple(str(name) for name in names)
    if not names:
        raise InputError(f"{where}: no landmark names given")
    for name in names:
        if not name.strip() or any(c in name for c in "\t\r\n") or name != name.strip():
            raise InputError(f"{where}: landmark name {name!r} is empty, has surrounding spaces, a tab or a line break")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise InputError(f"{where}: landmark names repeat: {', '.join(duplicates)}")
    return names


def _check_positions(positions: np.ndarray, count: int, where: str) -> np.ndarray:
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[1:] != (count, 3):
        raise InputError(f"{where}: positions must have shape [T, {count}, 3] (one xyz per frame and name), got {list(positions.shape)}")
    if np.isinf(positions).any():
        raise InputError(f"{where}: positions hold infinite values (NaN marks a missing one)")
    return positions


def _check_times(times: np.ndarray, count: int, where: str) -> np.ndarray:
    times = np.asarray(times, dtype=np.float64)
    if times.shape != (count,):
        raise InputError(f"{where}: times must have shape [{count}] (one per frame of positions), got {list(times.shape)}")
    if not np.isfinite(times).all():
        raise InputError(f"{where}: times must be finite")
    return times


def _check_rate(rate: float, where: str) -> float:
    rate = float(rate)
    if not math.isfinite(rate) or rate <= 0:
        raise InputError(f"{where}: rate must be a positive number of frames per second, got {rate}")
    return rate


def _number(value: float) -> str:
    """``value`` as text that reads back exactly; an empty cell for NaN."""
    value = float(value)
    if math.isnan(value):
        return ""
    return repr(value)


def _rate_text(rate: float) -> str:
    return str(int(rate)) if float(rate).is_integer() else repr(float(rate))


def _read_text(path: Path, kind: str) -> str:
    if not path.is_file():
        raise MissingFileError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: not a {kind} file (not UTF-8 text at byte {error.start})") from None


def _float_cell(text: str, where: str, what: str, missing_ok: bool = True) -> float:
    text = text.strip()
    if not text:
        if missing_ok:
            return math.nan
        raise InputError(f"{where}: {what} is empty")
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{where}: {what} {text!r} is not a number") from None
    if math.isinf(value):
        raise InputError(f"{where}: {what} {text!r} is infinite")
    if math.isnan(value) and not missing_ok:
        raise InputError(f"{where}: {what} is NaN")
    return value


def _int_cell(text: str, where: str, what: str) -> int:
    value = _float_cell(text, where, what, missing_ok=False)
    if not value.is_integer():
        raise InputError(f"{where}: {what} {text.strip()!r} is not a whole number")
    return int(value)


# --- TRC -----------------------------------------------------------------------------------------------------


def _turned(positions: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``axes @ p`` for every point p of ``positions`` [..., 3], ``axes`` a signed permutation: by picking and
    negating coordinates, so that a point missing one coordinate leaves the others as they were."""
    index = np.abs(axes).argmax(axis=1)
    return positions[..., index] * axes[np.arange(3), index]


def _check_convention(convention: str) -> None:
    if convention not in TRC_CONVENTIONS:
        raise InputError(f"unknown TRC axis convention {convention!r}: use one of {', '.join(TRC_CONVENTIONS)}")


def read_trc(path: str | os.PathLike, convention: str = "pose2sim") -> TrcData:
    """Read a TRC file (module docstring): positions in metres in mmcsplat's world frame under ``convention``
    (``"pose2sim"``: world = (trc Z, trc X, trc Y); ``"none"``: as in the file). Raises
    :class:`~mmcsplat.plugin_api.errors.InputError` naming the file and line at fault."""
    _check_convention(convention)
    path = Path(path)
    lines = _read_text(path, "TRC").splitlines()

    def line(number: int) -> list[str]:
        if len(lines) < number:
            raise InputError(f"{path}, line {number}: the file ends inside the TRC header ({len(lines)} line(s))")
        return lines[number - 1].split("\t")

    if line(1)[0].split()[:1] != ["PathFileType"]:  # OpenCap's writes a space after it, not a tab
        raise InputError(f"{path}, line 1: not a TRC file (it starts {lines[0][:40]!r}, a TRC file with 'PathFileType')")
    keys, values = [cell.strip() for cell in line(2)], [cell.strip() for cell in line(3)]
    while keys and not keys[-1]:
        keys.pop()
    missing = [key for key in ("DataRate", "NumFrames", "NumMarkers", "Units") if key not in keys]
    if missing:
        raise InputError(f"{path}, line 2: TRC header keys lack {', '.join(missing)} (found {' '.join(keys)!r})")
    if len(values) < len(keys) or any(not values[i] for i in range(len(keys))):
        raise InputError(f"{path}, line 3: {len(keys)} header values expected (one per key of line 2), got {' '.join(values)!r}")
    header = dict(zip(keys, values, strict=False))
    rate = _float_cell(header["DataRate"], f"{path}, line 3", "DataRate", missing_ok=False)
    if rate <= 0:
        raise InputError(f"{path}, line 3: DataRate must be positive, got {header['DataRate']}")
    num_frames = _int_cell(header["NumFrames"], f"{path}, line 3", "NumFrames")
    num_markers = _int_cell(header["NumMarkers"], f"{path}, line 3", "NumMarkers")
    units = header["Units"]
    if units not in _UNITS:
        raise InputError(f"{path}, line 3: Units {units!r} is not supported (m or mm)")

    labels = line(4)
    if [cell.strip() for cell in labels[:2]] != ["Frame#", "Time"]:
        raise InputError(f"{path}, line 4: TRC marker line must start with 'Frame#' and 'Time', got {lines[3][:40]!r}")
    names = tuple(cell.strip() for cell in labels[2:] if cell.strip())
    if len(names) != num_markers:
        raise InputError(f"{path}, line 4: {len(names)} marker name(s) but NumMarkers (line 3) is {num_markers}")
    if len(set(names)) != len(names):
        repeated = sorted({name for name in names if names.count(name) > 1})
        raise InputError(f"{path}, line 4: marker names repeat: {', '.join(repeated)}")
    line(5)  # the X1 Y1 Z1 … line

    cells_per_row = 2 + 3 * len(names)
    frame_numbers, times, rows = [], [], []
    for number in range(6, len(lines) + 1):
        text = lines[number - 1]
        if not text.strip():
            continue  # OpenSim's files hold a blank line after the header; a trailing one is common
        where = f"{path}, line {number}"
        cells = text.split("\t")
        if len(cells) > cells_per_row and not any(cell.strip() for cell in cells[cells_per_row:]):
            cells = cells[:cells_per_row]  # trailing empty cells
        if len(cells) != cells_per_row:
            raise InputError(f"{where}: {len(cells)} cells, expected {cells_per_row} (Frame#, Time and X Y Z for each of {len(names)} markers)")
        frame_numbers.append(_int_cell(cells[0], where, "Frame#"))
        times.append(_float_cell(cells[1], where, "Time", missing_ok=False))
        row = [_float_cell(cells[2 + i], where, f"{'XYZ'[i % 3]} of {names[i // 3]}") for i in range(3 * len(names))]
        rows.append(row)
    if len(rows) != num_frames:
        raise InputError(f"{path}, line 3: NumFrames is {num_frames} but the file has {len(rows)} frame row(s) (truncated?)")

    positions = np.asarray(rows, dtype=np.float64).reshape(len(rows), len(names), 3) * _UNITS[units]
    start = _int_cell(header["OrigDataStartFrame"], f"{path}, line 3", "OrigDataStartFrame") if header.get("OrigDataStartFrame") else 0
    if start == 1:  # Pose2Sim's frame 1 (its first row one frame in), or a 1-based writer's first frame
        start = int(bool(times) and abs(times[0] * rate - 1) < 0.5)
    return TrcData(names=names, frame_numbers=np.asarray(frame_numbers, dtype=np.int64), times=np.asarray(times, dtype=np.float64),
                   positions=_turned(positions, TRC_AXES[convention]), rate=rate, units=units,
                   incomplete=header.get(TRC_INCOMPLETE_KEY), first_frame=max(start, 0))


def write_trc(path: str | os.PathLike, names: Sequence[str], times: np.ndarray, positions: np.ndarray, rate: float,
              convention: str = "pose2sim", units: str = "m", incomplete: str | None = None, first_frame: int = 0) -> None:
    """Write ``positions`` [T, L, 3] (world metres, NaN where missing) as a TRC file (module docstring), atomically.

    Frame numbers are 1..T, ``times`` [T] the Time column (the capture's times), ``rate`` the DataRate
    (and CameraRate, OrigDataRate); line 1 names the file itself. ``convention`` maps world axes to the
    file's (``"pose2sim"``: file (X, Y, Z) = (world y, world z, world x), Y up); ``units`` ``"m"`` or ``"mm"``.
    ``incomplete``, what is unfinished in the run exported, becomes the header key ``Incomplete``. ``first_frame``,
    the capture's frame of the first row, is written as ``OrigDataStartFrame`` so that :func:`read_trc` places
    the rows again: 1 for frame 0 (OpenSim's numbering from 1), the frame itself after it (Pose2Sim's)."""
    path = Path(path)
    _check_convention(convention)
    if units not in _UNITS:
        raise InputError(f"{path}: TRC units must be m or mm, got {units!r}")
    names = _check_names(names, str(path))
    positions = _check_positions(positions, len(names), str(path))
    times = _check_times(times, len(positions), str(path))
    rate = _check_rate(rate, str(path))
    if "\t" in path.name or "\n" in path.name:
        raise InputError(f"{path}: a TRC file name may not hold a tab or a line break")

    values = _turned(positions, TRC_AXES[convention].T) / _UNITS[units]
    count = len(values)
    out = io.StringIO()
    out.write(f"PathFileType\t4\t(X/Y/Z)\t{path.name}\n")
    header = {**dict(zip(TRC_HEADER_KEYS, [_rate_text(rate), _rate_text(rate), str(count), str(len(names)), units, _rate_text(rate), str(max(first_frame, 1)),
                                            str(count)], strict=True)),
              **({TRC_INCOMPLETE_KEY: _one_line(incomplete)} if incomplete else {})}
    out.write("\t".join(header) + "\n")
    out.write("\t".join(header.values()) + "\n")
    out.write("Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t\n")
    out.write("\t\t" + "\t".join(f"{axis}{i}" for i in range(1, len(names) + 1) for axis in "XYZ") + "\n")
    for k in range(count):
        out.write(f"{k + 1}\t{_number(times[k])}\t" + "\t".join(_number(v) for v in values[k].ravel()) + "\n")
    write_text_atomic(path, out.getvalue())


# --- CSV -----------------------------------------------------------------------------------------------------


def write_landmark_csv(path: str | os.PathLike, names: Sequence[str], frames: np.ndarray, times: np.ndarray, positions: np.ndarray,
                       extra: Mapping[str, np.ndarray] | None = None) -> None:
    """Write the long-format CSV (module docstring) atomically: one row ``frame,time,name,x,y,z[,extra…]``
    per frame and landmark, frames in the order given, NaN as an empty cell. ``extra`` maps column names to
    [T, L] arrays (e.g. ``spread_mm``, ``confidence``)."""
    path = Path(path)
    names = _check_names(names, str(path))
    positions = _check_positions(positions, len(names), str(path))
    count = len(positions)
    times = _check_times(times, count, str(path))
    frames = np.asarray(frames)
    if frames.shape != (count,) or not np.issubdtype(frames.dtype, np.number) or not np.all(np.mod(frames, 1) == 0):
        raise InputError(f"{path}: frames must be {count} whole numbers (one per frame of positions), got {frames.shape[0] if frames.ndim else 0}")
    frames = frames.astype(np.int64)
    if len(set(frames.tolist())) != count:
        raise InputError(f"{path}: frame numbers repeat")
    columns = {}
    for column, values in (extra or {}).items():
        if not column or column != column.strip() or column in CSV_COLUMNS or any(c in column for c in ",\"\r\n"):
            raise InputError(f"{path}: extra column name {column!r} is empty, a base column or holds a comma, quote or line break")
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (count, len(names)):
            raise InputError(f"{path}: extra column {column!r} must have shape [{count}, {len(names)}], got {list(values.shape)}")
        columns[column] = values

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*CSV_COLUMNS, *columns])
    for k in range(count):
        frame, time = str(int(frames[k])), _number(times[k])
        for i, name in enumerate(names):
            writer.writerow([frame, time, name, *(_number(v) for v in positions[k, i]), *(_number(values[k, i]) for values in columns.values())])
    write_text_atomic(path, out.getvalue())


def read_landmark_csv(path: str | os.PathLike) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Read a landmark CSV (module docstring): ``(names, frames [T], times [T], positions [T, L, 3], extra
    {column: [T, L]})``, frames sorted, names in order of first appearance, NaN where a cell is empty or a
    (frame, name) row is absent. The short form ``name,x,y,z`` reads as frame 0 at time 0. Raises
    :class:`~mmcsplat.plugin_api.errors.InputError` naming the file and line at fault."""
    path = Path(path)
    reader = csv.reader(io.StringIO(_read_text(path, "CSV"), newline=""))
    try:
        header = [cell.strip() for cell in next(reader)]
    except StopIteration:
        raise InputError(f"{path}, line 1: the file is empty (a landmark CSV starts with {','.join(CSV_COLUMNS)})") from None
    except csv.Error as error:
        raise InputError(f"{path}, line 1: not a CSV header ({error})") from None
    lowered = [cell.lower() for cell in header]
    if tuple(lowered[:6]) == CSV_COLUMNS:
        base = CSV_COLUMNS
    elif tuple(lowered[:4]) == CSV_SHORT_COLUMNS:
        base = CSV_SHORT_COLUMNS
    else:
        raise InputError(f"{path}, line 1: header {','.join(header)[:80]!r} is neither {','.join(CSV_COLUMNS)} nor {','.join(CSV_SHORT_COLUMNS)} (then extra columns)")
    extra_names = header[len(base):]
    if any(not column for column in extra_names) or len(set(lowered)) != len(lowered):
        raise InputError(f"{path}, line 1: extra column names must be present and distinct, got {','.join(header)[:80]!r}")

    names: dict[str, int] = {}
    frame_times: dict[int, float] = {}
    cells: dict[tuple[int, str], list[float]] = {}
    try:
        for row in reader:
            where = f"{path}, line {reader.line_num}"
            if not row or not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                raise InputError(f"{where}: {len(row)} cells, expected {len(header)} ({','.join(header)[:80]})")
            values = dict(zip(lowered[:len(base)], row, strict=False))
            if base is CSV_COLUMNS:
                frame = _int_cell(values["frame"], where, "frame")
                time = _float_cell(values["time"], where, "time", missing_ok=False)
                if frame_times.setdefault(frame, time) != time:
                    raise InputError(f"{where}: time {time} of frame {frame} differs from {frame_times[frame]} on an earlier row")
            else:
                frame = 0
                frame_times[0] = 0.0
            name = values["name"].strip()
            if not name:
                raise InputError(f"{where}: the name is empty")
            if (frame, name) in cells:
                raise InputError(f"{where}: a second row for {name!r} at frame {frame}")
            names.setdefault(name, len(names))
            coordinates = [_float_cell(values[axis], where, axis) for axis in "xyz"]
            cells[frame, name] = coordinates + [_float_cell(row[len(base) + j], where, column) for j, column in enumerate(extra_names)]
    except csv.Error as error:
        raise InputError(f"{path}, line {reader.line_num}: unreadable CSV ({error})") from None
    if not cells:
        raise InputError(f"{path}, line 2: no landmark rows after the header")

    frames = np.asarray(sorted(frame_times), dtype=np.int64)
    index = {int(frame): k for k, frame in enumerate(frames)}
    table = np.full((len(frames), len(names), 3 + len(extra_names)), np.nan)
    for (frame, name), values in cells.items():
        table[index[frame], names[name]] = values
    times = np.asarray([frame_times[int(frame)] for frame in frames], dtype=np.float64)
    extra = {column: table[..., 3 + j].copy() for j, column in enumerate(extra_names)}
    return tuple(names), frames, times, table[..., :3].copy(), extra


# --- C3D -----------------------------------------------------------------------------------------------------


def write_c3d(path: str | os.PathLike, names: Sequence[str], times: np.ndarray, positions: np.ndarray, rate: float,
              incomplete: str | None = None) -> None:
    """Write ``positions`` [T, L, 3] (world metres, NaN where missing) as C3D POINT data through ezc3d, atomically.

    Values are written in millimetres (``POINT:UNITS = "mm"``) with ``POINT:LABELS`` = ``names`` and
    ``POINT:RATE`` = ``rate``. C3D has no fixed up axis, so mmcsplat's world frame is written unchanged
    (no axis swap, unlike TRC). A missing point is written as 0 with residual -1 (C3D's invalid point),
    a known one with residual 0. C3D holds a rate, not times: frame k is at k / rate from the first, so
    ``times`` must be evenly spaced at 1 / ``rate`` (an InputError otherwise: a gap would be lost).
    ``incomplete``, what is unfinished in the run exported, becomes the parameter ``MMCSPLAT:INCOMPLETE``."""
    import ezc3d

    path = Path(path)
    names = _check_names(names, str(path))
    positions = _check_positions(positions, len(names), str(path))
    times = _check_times(times, len(positions), str(path))
    rate = _check_rate(rate, str(path))
    if len(positions) == 0:
        raise InputError(f"{path}: no frames to write")
    steps = np.diff(times) * rate
    if steps.size and np.abs(steps - 1).max() > 0.5:
        k = int(np.argmax(np.abs(steps - 1)))
        raise InputError(f"{path}: C3D frames are evenly spaced at 1/{_rate_text(rate)} s, but times {times[k]:.6g} s and "
                         f"{times[k + 1]:.6g} s are {steps[k]:.3g} frames apart (export contiguous frames)")

    known = np.isfinite(positions).all(axis=-1)  # [T, L]
    points = np.ones((4, len(names), len(positions)))
    points[:3] = np.where(known[..., None], positions * 1000.0, 0.0).transpose(2, 1, 0)
    residuals = np.where(known, 0.0, -1.0).T[None]
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = np.array([rate])
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(names)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals}
    if incomplete:
        c3d.add_parameter(*C3D_INCOMPLETE_PARAMETER, [_one_line(incomplete)])
    with atomic_path(path) as temporary:
        written = temporary.with_name(temporary.name + ".c3d")  # ezc3d appends .c3d to a path that does not end so
        try:
            c3d.write(str(written))
            os.replace(written, temporary)
        finally:
            written.unlink(missing_ok=True)


def read_c3d(path: str | os.PathLike) -> tuple[tuple[str, ...], np.ndarray, float]:
    """Read C3D POINT data through ezc3d: ``(names, positions [T, L, 3] in metres, rate)``, axes as in the
    file, NaN for an invalid point (negative residual). Units m, cm or mm."""
    import ezc3d

    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        c3d = ezc3d.c3d(str(path))
    except Exception as error:  # ezc3d raises plain RuntimeErrors/IOErrors on a file it cannot parse
        raise InputError(f"{path}: not a readable C3D file ({str(error).splitlines()[0] if str(error) else type(error).__name__})") from None
    point = c3d["parameters"]["POINT"]
    names = tuple(str(label).strip() for label in point["LABELS"]["value"])
    units = "".join(point["UNITS"]["value"]).strip() if "UNITS" in point else ""
    if units not in _C3D_UNITS:
        raise InputError(f"{path}: POINT:UNITS {units!r} is not supported (m, cm or mm)")
    rate = float(np.asarray(point["RATE"]["value"]).ravel()[0])
    points = np.asarray(c3d["data"]["points"], dtype=np.float64)[:3]  # [3, L, T]
    positions = points.transpose(2, 1, 0) * _C3D_UNITS[units]
    residuals = c3d["data"]["meta_points"].get("residuals") if "meta_points" in c3d["data"] else None
    if residuals is not None and np.size(residuals):
        positions[np.asarray(residuals)[0].T < 0] = np.nan
    if len(names) != positions.shape[1]:
        raise InputError(f"{path}: {len(names)} POINT:LABELS for {positions.shape[1]} points")
    return names, positions, rate
