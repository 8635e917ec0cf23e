"""Caliscope's frame timing beside its videos: frame k of every camera's video must be one moment.

Caliscope's recorder writes ``timestamps.csv`` (``sync_index,cam_id,frame_time``) beside ``cam_N.mp4``:
one row per frame of camera N, the rows of one moment sharing a ``sync_index``; its player takes camera
N's k-th frame as the k-th of its times in the file. Frame k of every video is then one moment exactly
when each sync index holds a row of every camera. A camera that missed a moment is a frame behind the
others from there on, and ingest, which pairs the videos frame by frame, cannot see it in the images: so
such a recording is refused, naming the camera and the first moment it lacks, as are a file whose rows
of a camera do not count its video's frames and one that lists a camera's moment twice. The file is read
only where every video is named ``cam_N`` as Caliscope names them; other files of that name are left alone.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping
from pathlib import Path

from mmcsplat.plugin_api.errors import InputError

TIMESTAMPS_FILE = "timestamps.csv"
HEADER = ("sync_index", "cam_id", "frame_time")
_VIDEO_STEM = re.compile(r"cam_(\d+)")


def check_caliscope_timing(videos: Mapping[str, Path], frames: Mapping[str, int]) -> None:
    """Refuse a Caliscope recording whose videos (camera name → path, all in one folder) are not frame by
    frame one moment per its ``timestamps.csv`` (module docstring); ``frames`` holds each video's frame count.
    Nothing is checked without that file beside the videos, or when a video is not named ``cam_N``."""
    folders = {path.parent for path in videos.values()}
    ids = {name: _VIDEO_STEM.fullmatch(path.stem) for name, path in videos.items()}
    if len(folders) != 1 or not all(ids.values()):
        return
    path = folders.pop() / TIMESTAMPS_FILE
    if not path.is_file():
        return
    with path.open(newline="") as file:
        rows = list(csv.reader(file))
    if not rows or tuple(cell.strip() for cell in rows[0]) != HEADER:
        return
    moments: dict[int, set[int]] = {int(match.group(1)): set() for match in ids.values()}
    for line, row in enumerate(rows[1:], start=2):
        try:
            sync_index, cam_id = int(row[0]), int(row[1])
        except (IndexError, ValueError):
            raise InputError(f"{path}, line {line}: expected {','.join(HEADER)} with whole numbers for the first two, got {row}") from None
        if cam_id in moments:
            if sync_index in moments[cam_id]:
                raise InputError(f"{path}, line {line}: camera cam_{cam_id} has sync index {sync_index} twice")
            moments[cam_id].add(sync_index)
    every = set().union(*moments.values())
    for name, match in ids.items():
        own = moments[int(match.group(1))]
        if len(own) != frames[name]:
            raise InputError(f"{path}: {len(own)} frames of camera {name}, but its video {videos[name].name} holds {frames[name]}: "
                             "the timestamps are not this recording's")
        if missing := sorted(every - own):
            later = f" and {len(missing) - 1} later one{'s' if len(missing) > 2 else ''}" if len(missing) > 1 else ""
            raise InputError(f"{path}: camera {name} has no frame at sync index {missing[0]}{later}, so "
                             "from there frame k of its video is another moment than the other cameras' frame k; leave it out with --cameras")
