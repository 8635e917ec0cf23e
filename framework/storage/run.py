"""A run directory's files, each named once: the first-frame fit writes ``run.json``, ``checkpoint.pt``,
``curves.csv`` and ``log.txt``; tracking adds ``tracks.zarr`` and ``track.json`` (and ``deformation.pt``
for the deformation method); evaluation ``metrics.json``; ``fit --folds`` ``folds.json`` above its folds; landmarks ``landmarks.csv``, ``landmarks.json``, ``movement.json``, ``movement.csv``
(and an exported TRC); renders go to ``renders/``, the report to ``report.html``.

Every module that reads or writes one of these names imports it from here (``tests/test_run_files.py``
fails on a literal anywhere else), so renaming a file, or finding who reads it, is one search.
"""

from __future__ import annotations

#: The fit's record (:class:`mmcsplat.storage.run_info.RunInfo`).
RUN_INFO = "run.json"
#: The first-frame fit's checkpoint: the training state to resume and, once complete, the fitted Gaussians.
CHECKPOINT = "checkpoint.pt"
#: Training curves of the fit and of tracking (:mod:`mmcsplat.storage.curves`).
CURVES_FILE = "curves.csv"
#: The run's log, appended by every step (:mod:`mmcsplat.storage.run_log`).
LOG_FILE = "log.txt"
#: The tracked Gaussians, frame by frame (:mod:`mmcsplat.storage.tracks`).
TRACKS_DIR = "tracks.zarr"
#: What tracking ran and how long it took.
TRACK_INFO = "track.json"
#: Written when a tracking starts and removed when it has finished: left behind, the tracking was killed
#: or failed, and whatever tracks the run holds are not the ones asked for.
TRACKING_UNFINISHED = "tracking.unfinished"
#: The deformation dynamics method's own checkpoint.
DEFORMATION_CHECKPOINT = "deformation.pt"
#: The evaluation's scores.
METRICS_FILE = "metrics.json"
#: The folds a leave-one-camera-out run (``fit --folds``) holds, planned before the first is fitted.
FOLDS_FILE = "folds.json"
#: The landmarks' positions per frame, and their record (source, binding, accuracy).
LANDMARKS_CSV = "landmarks.csv"
LANDMARKS_INFO = "landmarks.json"
#: The landmarks' movement measures (:mod:`mmcsplat.analysis.movement`), as JSON and as one row per measure.
MOVEMENT_JSON = "movement.json"
MOVEMENT_CSV = "movement.csv"
#: The landmarks exported for OpenSim / Pose2Sim.
LANDMARKS_TRC = "landmarks.trc"
#: The folder of rendered videos and figures, and the novel-view path video in it.
RENDERS_DIR = "renders"
NOVEL_VIDEO = "novel.mp4"
#: The HTML report.
REPORT_FILE = "report.html"
#: What is made of a run's Gaussians (its fit and tracks): new tracks, and a fit resumed, remove them, so that
#: none describes tracks gone, a run of one frame, or a fit stopped half way.
MADE_OF_THE_MODEL = (METRICS_FILE, LANDMARKS_CSV, LANDMARKS_INFO, MOVEMENT_JSON, MOVEMENT_CSV, LANDMARKS_TRC, RENDERS_DIR, REPORT_FILE)
