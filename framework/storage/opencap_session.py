"""An OpenCap session's layout: one trial's synchronised video from each phone, and its markers.

OpenCap's session (the web app's download, ``OpenCapData_<id>/``) keeps each phone's recordings in
``Videos/CamN/InputMedia/<trial>/``: the upload as recorded (``<trial>.mov``) and ``<trial>_sync.mp4``,
cut so that frame k of every phone's is the same moment (and row k of the trial's ``MarkerData`` TRC),
at half the recorded resolution. The uploads start at different moments and are not read; the
synchronised videos are, and their calibration (:mod:`mmcsplat.storage.opencap_calibration`, which states
the recorded size) is scaled to them by the reader's ``size_mismatch`` rule, with a warning.

A session holds several trials (a neutral pose beside the movements): one is chosen by the reader's
``trial`` parameter (``--reader-set trial=NAME``), or is the only one. The trial's markers, OpenCap's
triangulation of its keypoints with the markers its model adds, are ``MarkerData/<trial>.trc``
(:data:`~.landmark_formats.TRC_AXES` says how its axes lie, :func:`trc_convention` which of them a session takes).

The phones' 2D keypoints (``Videos/CamN/OutputPkl/<trial>_keypoints.pkl``) are numbered by the uploads'
frames, whose start in the synchronised videos the download does not keep: the ``opencap`` keypoint source
places them by the trial's markers.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.storage.calibration import read_rig
from mmcsplat.storage.camera_names import natural_key
from mmcsplat.storage.opencap_calibration import is_opencap, opencap_convention, opencap_files
from mmcsplat.storage.session import SessionReader

#: Where a session keeps its cameras' folders, and where a camera's folder keeps its trials' videos.
SESSION_VIDEOS = "Videos"
INPUT_MEDIA = "InputMedia"
#: What ends a trial's synchronised video's name, after the trial's.
SYNCHRONISED = "_sync.mp4"
#: Where a session keeps each trial's markers, ``<trial>.trc``.
MARKER_DATA = "MarkerData"
#: Where a camera's folder keeps its trials' 2D keypoints, ``<trial>_keypoints.pkl``.
OUTPUT_PKL = "OutputPkl"
KEYPOINTS_SUFFIX = "_keypoints.pkl"


def is_opencap_session(source: Path) -> bool:
    """Whether ``source`` is an OpenCap session: calibrated camera folders in its ``Videos/``."""
    return bool(opencap_files(Path(source) / SESSION_VIDEOS))


def _synchronised(source: Path, camera: str, trial: str) -> Path:
    return Path(source) / SESSION_VIDEOS / camera / INPUT_MEDIA / trial / f"{trial}{SYNCHRONISED}"


def opencap_trials(source: Path) -> list[str]:
    """The trials of which some camera of the session has a synchronised video, in name order."""
    found = {path.parent.name for path in (Path(source) / SESSION_VIDEOS).glob(f"*/{INPUT_MEDIA}/*/*{SYNCHRONISED}")
             if path.name == f"{path.parent.name}{SYNCHRONISED}"}
    return sorted(found, key=natural_key)


def opencap_trial(source: Path, trial: str | None) -> str:
    """``trial`` if the session has it, else its only trial when None; an error naming the trials otherwise."""
    trials = opencap_trials(source)
    if not trials:
        raise MissingFileError(f"OpenCap session {source}: no synchronised video ({SESSION_VIDEOS}/CamN/{INPUT_MEDIA}/TRIAL/TRIAL{SYNCHRONISED}); "
                               "the uploads beside them are not synchronised with each other")
    if trial is None:
        if len(trials) > 1:
            raise InputError(f"OpenCap session {source}: trials {', '.join(trials)}; choose one with --reader-set trial=NAME")
        trial = trials[0]
    elif trial not in trials:
        raise MissingFileError(f"OpenCap session {source}: no synchronised video of trial {trial!r} (trials: {', '.join(trials)})")
    return trial


def opencap_videos(source: Path, cameras: Sequence[str], trial: str | None) -> dict[str, Path]:
    """Camera → its synchronised video of ``trial`` (:func:`opencap_trial`): an error naming the camera
    without it."""
    source = Path(source)
    trial = opencap_trial(source, trial)
    videos = {camera: _synchronised(source, camera, trial) for camera in cameras}
    missing = [camera for camera, path in videos.items() if not path.is_file()]
    if missing:
        raise MissingFileError(f"OpenCap session {source}: no {videos[missing[0]].relative_to(source)} (trial {trial!r} lacks "
                               f"camera{'s' if len(missing) > 1 else ''} {', '.join(missing)}); leave "
                               f"{'them' if len(missing) > 1 else 'it'} out with --cameras")
    return videos


def opencap_markers(source: Path, trial: str | None) -> Path | None:
    """The markers of ``trial`` (:func:`opencap_trial`) when ``source`` is an OpenCap session that has them and
    was calibrated on a board lying on the floor, else None (with a warning when it has them).

    OpenCap lifts a trial's markers so that the lowest stands 1 cm up, and keeps the lift only in a file
    its download leaves out (``Settings_<trial>.yaml``'s ``verticalOffset``). With the board on the floor
    its plane is the floor, so the lift is the feet's markers' own height, a few centimetres: the markers
    still bind to the body at the fitted frame, and are scored against the same lifted markers. With the
    board on a wall the lift is the board's height above the floor: the markers would lie a metre from
    the body, so they are not taken."""
    if not is_opencap_session(source):
        return None
    path = Path(source) / MARKER_DATA / f"{opencap_trial(Path(source), trial)}.trc"
    if not path.is_file():
        return None
    placement = _placement(source)
    if placement != "opencap-ground":
        warnings.warn(f"{path}: not taken as the joints: the session was calibrated on a board on a wall ({placement}), and OpenCap lifts "
                      "its markers by the board's height, which the download does not keep (Settings_<trial>.yaml's verticalOffset); "
                      "give markers without the lift with --joints", stacklevel=2)
        return None
    return path.resolve()


def placeable_keypoints(source: Path) -> bool:
    """Whether ``source`` is an OpenCap session whose phones' keypoints its markers can place: it keeps
    keypoints (``Videos/CamN/OutputPkl/``) and markers, and was calibrated on a board lying on the floor (a
    wall board's markers are lifted by an unknown height: :func:`opencap_markers`)."""
    source = Path(source)
    if not is_opencap_session(source) or not any(source.glob(f"{SESSION_VIDEOS}/*/{OUTPUT_PKL}/*{KEYPOINTS_SUFFIX}")) \
            or not any((source / MARKER_DATA).glob("*.trc")):
        return False
    return _placement(source) == "opencap-ground"


def _placement(source: Path) -> str:
    """The TRC convention of the OpenCap session ``source``'s markers, by its board's placement, told from its
    cameras (:func:`~.opencap_calibration.opencap_convention`)."""
    calibration = opencap_files(Path(source) / SESSION_VIDEOS)[0]
    return opencap_convention(read_rig(calibration).cameras, f"calibration {calibration}")


def trc_convention(session: SessionReader) -> str:
    """The axes a TRC of ``session``'s world takes (:data:`~.landmark_formats.TRC_AXES`): OpenCap's, by its
    board's placement (:func:`~.opencap_calibration.opencap_convention`), where the session was calibrated
    by OpenCap, so that its Y is up and its markers meet it; Pose2Sim's (a Z-up world) otherwise."""
    calibration = session.provenance.get("reader", {}).get("calibration")
    if calibration is None or not is_opencap(Path(calibration)):
        return "pose2sim"
    return opencap_convention([session.camera(name) for name in session.camera_names], f"session {session.url}")
