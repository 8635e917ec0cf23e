"""Caliscope's frame timing beside its videos: which moment each frame of each camera's video is.

Caliscope's recorder writes ``timestamps.csv`` (``sync_index,cam_id,frame_time``) beside ``cam_N.mp4``:
one row per frame of camera N, the rows of one moment sharing a ``sync_index``; its player takes camera
N's k-th frame as the k-th of its times in the file. Frame k of every video is one moment exactly when
each sync index holds a row of every camera. A camera that missed a moment is a frame behind the others
from there on, which ingest, pairing the videos frame by frame, could not see in the images. So the
recording's frames are its moments (every sync index, in order), and each camera's video frames are
placed at theirs: a moment a camera missed is absent for it, or, by default, an error naming the camera
and the first moment it lacks. A moment's time is the mean of its cameras' ``frame_time``, from the first
moment's: the recording's own clock, which a nominal frame rate only approximates (Caliscope's own test
recording at 6 fps spaces its moments 0.154–0.181 s apart). A file whose rows of a camera do not count its
video's frames, or that lists a camera's moment twice, is refused. The file is read only where every video is named ``cam_N`` as
Caliscope names them; other files of that name are left alone.
"""

from __future__ import annotations

import csv
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError

TIMESTAMPS_FILE = "timestamps.csv"
HEADER = ("sync_index", "cam_id", "frame_time")
_VIDEO_STEM = re.compile(r"cam_(\d+)")


@attrs.frozen
class CaliscopeTiming:
    """A Caliscope recording's moments as its ``path`` (``timestamps.csv``) states them: ``placed[camera][t]``
    the video frame of moment ``t`` (``None`` where the camera missed it), ``times[t]`` its seconds from the
    first moment."""

    path: Path
    placed: dict[str, list[int | None]]
    times: np.ndarray

    def check_frames(self, videos: Mapping[str, Path], frames: Mapping[str, int]) -> None:
        """Refuse the timing where a camera's rows do not count its video's ``frames`` (name → count; ``videos``
        name → path, for the message): then the file is not this recording's."""
        for name, placed in self.placed.items():
            rows = sum(k is not None for k in placed)
            if rows != frames[name]:
                raise InputError(f"{self.path}: {rows} frames of camera {name}, but its video {videos[name].name} holds {frames[name]}: "
                                 "the timestamps are not this recording's")


def caliscope_frames(videos: Mapping[str, Path], missing_frames: str = "error") -> CaliscopeTiming | None:
    """The moments of a Caliscope recording, or ``None`` where no ``timestamps.csv`` applies (module
    docstring). ``videos`` maps camera names to their videos (all in one folder); a missed moment is an
    error unless ``missing_frames`` is ``"absent"``, then a warning counting them. Read before the videos
    are decoded, so a file that cannot apply is refused at once; :meth:`CaliscopeTiming.check_frames` checks it
    against their frame counts once they are known."""
    folders = {path.parent for path in videos.values()}
    ids = {name: _VIDEO_STEM.fullmatch(path.stem) for name, path in videos.items()}
    if len(folders) != 1 or not all(ids.values()):
        return None
    path = folders.pop() / TIMESTAMPS_FILE
    if not path.is_file():
        return None
    with path.open(newline="") as file:
        rows = list(csv.reader(file))
    if not rows or tuple(cell.strip() for cell in rows[0]) != HEADER:
        return None
    moments: dict[int, set[int]] = {int(match.group(1)): set() for match in ids.values()}
    clock: dict[int, list[float]] = {}
    for line, row in enumerate(rows[1:], start=2):
        try:
            sync_index, cam_id, seconds = int(row[0]), int(row[1]), float(row[2])
        except (IndexError, ValueError):
            raise InputError(f"{path}, line {line}: expected {','.join(HEADER)}, whole numbers and then seconds, got {row}") from None
        if not np.isfinite(seconds):
            raise InputError(f"{path}, line {line}: frame_time {row[2]} is not a time")
        if cam_id in moments:
            if sync_index in moments[cam_id]:
                raise InputError(f"{path}, line {line}: camera cam_{cam_id} has sync index {sync_index} twice")
            moments[cam_id].add(sync_index)
            clock.setdefault(sync_index, []).append(seconds)
    every = sorted(set().union(*moments.values()))
    placed: dict[str, list[int | None]] = {}
    gaps: dict[str, list[int]] = {}
    for name, match in ids.items():
        own = moments[int(match.group(1))]
        frame_of = {index: k for k, index in enumerate(sorted(own))}
        placed[name] = [frame_of.get(index) for index in every]
        if missing := [index for index in every if index not in frame_of]:
            gaps[name] = missing
    if gaps and missing_frames == "error":
        name, missing = next(iter(gaps.items()))
        later = f" and {len(missing) - 1} later one{'s' if len(missing) > 2 else ''}" if len(missing) > 1 else ""
        raise InputError(f"{path}: camera {name} has no frame at sync index {missing[0]}{later}, so from there frame k of its video "
                         "is another moment than the other cameras' frame k; pass --skip-missing to mmcsplat ingest (the reader "
                         "option missing_frames=absent) to ingest it with those moments absent, or leave it out with --cameras")
    if gaps:
        detail = "; ".join(f"{name} lacks {len(missing)} (first sync index {missing[0]})" for name, missing in gaps.items())
        warnings.warn(f"{path}: of {len(every)} moments, {detail}: those frames are absent", stacklevel=3)
    times = np.array([np.mean(clock[index]) for index in every])
    if np.any(np.diff(times) <= 0):
        t = int(np.flatnonzero(np.diff(times) <= 0)[0])
        raise InputError(f"{path}: sync index {every[t + 1]} is no later than sync index {every[t]} by its frame times: the clock is not this recording's")
    return CaliscopeTiming(path, placed, times - times[0])
