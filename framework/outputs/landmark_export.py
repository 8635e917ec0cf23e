"""``mmcsplat export RUN --trc / --csv / --c3d``: a run's carried landmarks (``RUN/landmarks.csv``) in the
files biomechanics tools read — TRC for OpenSim and Pose2Sim (Y-up, Pose2Sim's axes), CSV for everyone,
C3D for motion-capture labs (:mod:`mmcsplat.storage.landmark_formats` has each format's conventions)."""

from __future__ import annotations

from pathlib import Path

from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import MissingFileError
from mmcsplat.storage.landmark_formats import read_landmark_csv, write_c3d, write_landmark_csv, write_trc
from mmcsplat.storage.run import LANDMARKS_CSV


def export_landmarks(run: str | Path, trc: str | Path | None = None, csv: str | Path | None = None, c3d: str | Path | None = None) -> list[Path]:
    """Write the landmarks of ``run`` to each file given; returns the paths written."""
    source = Path(run) / LANDMARKS_CSV
    if not source.is_file():
        raise MissingFileError(f"{source} does not exist: `mmcsplat landmarks {run} --source …` carries landmarks first")
    names, frames, times, positions, extra = read_landmark_csv(source)
    rate = RunStates(run).session.fps
    written = []
    if trc is not None:
        write_trc(trc, names, times, positions, rate)
        written.append(Path(trc))
    if csv is not None:
        write_landmark_csv(csv, names, frames, times, positions, extra=extra)
        written.append(Path(csv))
    if c3d is not None:
        write_c3d(c3d, names, times, positions, rate)
        written.append(Path(c3d))
    return written
