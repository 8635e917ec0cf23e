"""A user's capture made into a session as ``mmcsplat run`` makes it — for that job and for a study's
capture sessions alike: ingested, then masks (the capture's own when it brings them for every training
camera; else, with 2D keypoints, the ``keypoints`` segmenter's skeleton; else the difference to the
capture's recorded plates, or with neither the ``parallax`` segmenter), plates estimated with those masks
holding the subject out (unless recorded), and the masks refined against the plates (docs/real-data.md); the
``parallax`` segmenter's masks twice, the plates estimated again with its refined masks held out.
A segmenter the user names (``run --segmenter``) makes the masks of every camera instead, as they stay:
the plates are estimated around them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mmcsplat.pipeline.image_scale import AUTO_SCALE
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import LandmarkSource
from mmcsplat.plugin_api.parameters import describe_parameters
from mmcsplat.scene.human_skeleton import TORSO, TORSO_NAMINGS
from mmcsplat.storage.calibration import AUTO_UNITS
from mmcsplat.storage.ground_truth import GROUND_TRUTH, GroundTruthReader
from mmcsplat.storage.opencap_session import is_opencap_session, opencap_markers, placeable_keypoints

#: The reader's parameters that say which file is whose: the keypoint source takes them too (:func:`keypoints_with`).
NAMING_OPTIONS = ("camera_map", "trial")
#: The scale ``mmcsplat run`` ingests a capture at (a real rig's full-size frames fit too slowly on a CPU).
DEFAULT_SCALE = AUTO_SCALE

if TYPE_CHECKING:  # for annotations: the session store's format is imported to make one, not for every command's start
    from mmcsplat.pipeline.segment import BuiltSegmenter
    from mmcsplat.storage.session import SessionReader


def found(capture: Path, given: str | None, pattern: str, what: str) -> Path | None:
    """``given``, else the single ``pattern`` match in ``capture`` (None when there is none)."""
    if given is not None:
        path = Path(given)
        if not path.exists():
            raise InputError(f"{what} {path} does not exist")
        return path.resolve()
    matches = sorted(capture.glob(pattern))
    if len(matches) > 1:
        raise InputError(f"{capture}: several {what} candidates ({', '.join(p.name for p in matches)}); choose one")
    return matches[0].resolve() if matches else None


#: Where a capture keeps its 2D keypoints, looked for in this order: older Pose2Sim's ``pose_2d``; today's Pose2Sim
#: poses associated across cameras, synchronised, then as detected (the order its triangulation takes them in);
#: anipose's filtered 2D poses (what it triangulates when its filter is on), then its raw ones.
KEYPOINT_FOLDERS = ("pose_2d", "pose-associated", "pose-sync", "pose", "pose-2d-filtered", "pose-2d")
#: :data:`KEYPOINT_FOLDERS` as an error message names them.
KEYPOINT_FOLDERS_NAMED = ", ".join(f"{name}/" for name in KEYPOINT_FOLDERS)


#: Where a FreeMoCap recording keeps its trackers' 2D keypoints: one file for every camera.
FREEMOCAP_KEYPOINTS = "output_data/raw_data/*2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy"
#: The keypoint suffix of a FreeMoCap 2D file, which :func:`keypoint_source` reads with the ``freemocap`` source.
FREEMOCAP_SUFFIX = ".npy"


#: Caliscope's body trackers (its calibration boards' aside), whose 2D keypoints a recording keeps in ``TRACKER/xy_TRACKER.csv``.
CALISCOPE_BODY_TRACKERS = ("ONNX_*", "POSE", "HOLISTIC", "SIMPLE_HOLISTIC")
#: How Caliscope names a tracker's 2D file, which :func:`keypoint_source` reads with the ``caliscope`` source.
CALISCOPE_PREFIX = "xy_"


def caliscope_keypoints(capture: Path) -> Path | None:
    """A Caliscope recording's body tracker's 2D file (:data:`CALISCOPE_BODY_TRACKERS`); None when it has none, an error
    naming them when it has several."""
    files = sorted({path for tracker in CALISCOPE_BODY_TRACKERS for path in capture.glob(f"{tracker}/{CALISCOPE_PREFIX}{tracker}.csv")})
    if len(files) > 1:
        raise InputError(f"{capture}: several Caliscope trackers' keypoints ({', '.join(path.parent.name for path in files)}); choose one "
                         "with --keypoints")
    return files[0].resolve() if files else None


def keypoint_folder(capture: Path, given: str | None) -> Path | None:
    """``given``, else the first of :data:`KEYPOINT_FOLDERS` that ``capture`` holds, else a FreeMoCap recording's
    2D file (:data:`FREEMOCAP_KEYPOINTS`), else a Caliscope recording's (:func:`caliscope_keypoints`), else an
    OpenCap session itself where its markers can place its phones' keypoints
    (:func:`~mmcsplat.storage.opencap_session.placeable_keypoints`); None when it holds none."""
    return next((path for name in KEYPOINT_FOLDERS if (path := found(capture, given, name, "keypoints")) is not None), None) \
        or found(capture, None, FREEMOCAP_KEYPOINTS, "FreeMoCap 2D keypoints file") or caliscope_keypoints(capture) \
        or (capture.resolve() if placeable_keypoints(capture) else None)


def joints_file(capture: Path, given: str | None, trial: str | None = None) -> Path | None:
    """``given``, else the capture's single ``*.trc``, else the single one in today's Pose2Sim's ``pose-3d/``
    (where its triangulation writes it), else an OpenCap session's markers of ``trial`` (its only trial when
    None: :func:`~mmcsplat.storage.opencap_session.opencap_markers`); None when there is none."""
    return found(capture, given, "*.trc", "joints TRC file") or found(capture, None, "pose-3d/*.trc", "joints TRC file") \
        or opencap_markers(capture, trial)


def joints_source(capture: Path, given: str | None, trial: str | None = None) -> dict[str, str] | None:
    """The landmarks plugin (``name``) and file (``path``) of the joints ``run`` carries and scores: a TRC
    (:func:`joints_file`; ``trial`` the reader's), else the true joints of a synthetic capture (its ``ground_truth.zarr``, written by
    ``mmcsplat synth``); None when the capture has neither."""
    trc = joints_file(capture, given, trial)
    if trc is not None:
        return {"name": "trc", "path": str(trc)}
    truth = capture / GROUND_TRUTH
    return {"name": "synthetic", "path": str(truth.resolve())} if truth.is_dir() and GroundTruthReader(truth).has("joints") else None


def start_with_joints(joints: Path | None, start: int | None, frames: str, fix: Callable[[int], str]) -> int | None:
    """The capture frame a run's frames must start at so its fitted frame binds the joints of ``joints``: None
    when ``start`` (None: the capture's first frame) has them already, else the frame a TRC's rows start at
    (:attr:`~mmcsplat.storage.landmark_formats.TrcData.first_frame`: today's Pose2Sim trims a trial to where the
    subject is seen). A ``start`` given before it is an :class:`InputError` naming ``frames`` (the caller's
    own words for them) and ``fix(first)``, how the caller's user gives that start."""
    from mmcsplat.storage.landmark_formats import read_trc

    first = read_trc(joints).first_frame if joints is not None and joints.suffix.lower() == ".trc" else 0
    if first <= (start or 0):
        return None
    if start is not None:
        raise InputError(f"{frames}: the joints {joints} start at the capture's frame {first} (its OrigDataStartFrame), so the "
                         f"fitted frame {start} has none: {fix(first)}")
    return first


def missing_torso(source: LandmarkSource, session: SessionReader, frame: int) -> str | None:
    """Why the joints ``source`` reads name no torso at session ``frame`` to size a human's parts by (its corners,
    :data:`~mmcsplat.scene.human_skeleton.TORSO_NAMINGS`, unknown there: an animal's keypoints, or detections missed in
    all but one camera), or None when they do."""
    landmarks = source.read(session, [frame])
    known = {name for name, position in zip(landmarks.names, landmarks.at(frame), strict=True) if np.isfinite(position).all()}
    if any(all(name in known for name in corners) for corners in TORSO_NAMINGS):
        return None
    corners = next((corners for corners in TORSO_NAMINGS if any(name in landmarks.names for name in corners)), TORSO)
    lacking = [name for name in corners if name not in known]
    named = [name for name in lacking if name in landmarks.names]
    return (f"{landmarks.source or 'the joints'} at frame {frame}: " + (f"{', '.join(named)} not known there" if named else
            f"no {', '.join(lacking)} among {', '.join(landmarks.names[:6])}{'…' if len(landmarks.names) > 6 else ''}"))


def keypoints_with(source: dict[str, Any], options: dict[str, Any], reader_options: dict[str, Any]) -> dict[str, Any]:
    """The keypoint source ``source`` (:func:`keypoint_source`) with the parameters ``options`` (``--keypoints-set``).
    The reader's :data:`NAMING_OPTIONS` (``--reader-set``, a study's ``reader``) name the keypoint files too, where
    the source takes them and ``options`` gives none of its own: a rig's keypoint folders and files are named after
    its videos (Pose2Sim's ``pose_2d/cam01`` beside ``videos/cam01.mp4``, anipose's ``pose-2d/vid01-camA.h5`` beside
    ``videos-raw/vid01-camA.avi``)."""
    from mmcsplat.configuration.registry import default_registry

    taken = {info.name for info in describe_parameters(default_registry().get("landmarks", source["name"]).load()) or ()}
    shared = {key: reader_options[key] for key in NAMING_OPTIONS if key in reader_options and key in taken}
    return {**source, **shared, **options}


def keypoint_source(path: Path) -> dict[str, Any]:
    """The landmarks plugin (``name``) and parameters that read the 2D keypoints at ``path``: a SLEAP file
    (``.slp``, ``.analysis.h5``), a DeepLabCut one (``.csv``, ``.h5``), FreeMoCap's (``.npy``) or Caliscope's (``xy_*.csv``), an OpenCap
    session (its phones' ``OutputPkl/``), or a folder of OpenPose camera folders of JSON files, else of SLEAP files, else of DeepLabCut files."""
    lower = path.name.lower()
    if path.is_file():
        if lower.endswith((".slp", ".analysis.h5")):
            return {"name": "sleap", "files": [str(path)]}
        if lower.startswith(CALISCOPE_PREFIX) and lower.endswith(".csv"):
            return {"name": "caliscope", "path": str(path)}
        if lower.endswith((".csv", ".h5")):
            return {"name": "deeplabcut", "files": [str(path)]}
        if lower.endswith(FREEMOCAP_SUFFIX):
            return {"name": "freemocap", "path": str(path)}
        raise InputError(f"keypoint file {path} is neither SLEAP (.slp, .analysis.h5), DeepLabCut (.csv, .h5), FreeMoCap (.npy) nor "
                         "Caliscope (xy_*.csv): give one of those, or a folder of OpenPose camera folders")
    if is_opencap_session(path):
        return {"name": "opencap", "path": str(path)}
    entries = sorted(path.iterdir())
    if any(entry.is_dir() and any(entry.glob("*.json")) for entry in entries):
        return {"name": "openpose", "folder": str(path)}
    if any(entry.is_file() and entry.name.lower().endswith((".slp", ".analysis.h5")) for entry in entries):
        return {"name": "sleap", "folder": str(path)}
    if any(entry.is_file() and entry.suffix.lower() in (".csv", ".h5") for entry in entries):
        return {"name": "deeplabcut", "folder": str(path)}
    raise InputError(f"keypoint folder {path} holds no OpenPose camera folders of JSON files, no SLEAP (.slp, .analysis.h5) and no "
                     "DeepLabCut (.csv, .h5) files")


def prepare_capture_session(capture: Path, partial: Path, *, calibration: Path | None = None, units: str = AUTO_UNITS, frames: slice | None = None,
                            scale: float | str = 1.0, cameras: Sequence[str] | None = None, holdout: Sequence[str] = (), source: dict[str, Any] | None = None,
                            reader_options: dict[str, Any] | None = None, segmenter: BuiltSegmenter | None = None,
                            progress: bool = True) -> dict[str, Any]:
    """Ingest ``capture`` into ``partial`` (its calibration, units, frames, scale, cameras, held-out cameras and
    reader options as :func:`~mmcsplat.pipeline.ingest.ingest` takes them) and give it masks and plates (module docstring), the
    masks from the 2D keypoints that ``source`` reads when given (:func:`keypoint_source`), or from ``segmenter`` when given;
    returns which masks it used (:func:`mask_choice`)."""
    from mmcsplat.pipeline.ingest import ingest
    from mmcsplat.pipeline.plates import estimate_plates
    from mmcsplat.pipeline.segment import segment_session
    from mmcsplat.storage.session import SessionReader

    ingest(capture, partial, calibration=calibration, units=units, frames=frames, scale=scale, cameras=cameras, holdout=list(holdout),
           overwrite=True, progress=progress, reader_options=reader_options)
    recorded = any(SessionReader(partial).plate(name) is not None for name in SessionReader(partial).camera_names)
    # The first masks hold the subject out of estimated plates; the refined ones (None: the first are final) are made against the
    # plates. Motion masks miss a still body in many of the plates' samples, so their plates keep its ghost: the refined masks,
    # which hold more of it, hold it out of the plates once more, and the masks are refined against those (a second round).
    name, first, refined, again = (segmenter.name, None, None, False) if segmenter else \
        ("keypoints", {"source": source}, {"source": source, "refine": "plate"}, False) if source else \
        ("background", {"method": "median"}, {"method": "plate"}, False) if recorded else ("parallax", {}, {"refine": "plate"}, True)
    choice = mask_choice(SessionReader(partial), name, chosen=segmenter is not None)
    made = choice["masks"] != "capture"
    if made and (not recorded or refined is None):
        segment_session(partial, segmenter or name, first, progress=progress)
    if not recorded:
        estimate_plates(str(partial), None, progress=progress)
    if made and refined is not None:
        segment_session(partial, name, refined, progress=progress)
        if again:
            estimate_plates(str(partial), None, replace=True, progress=progress)
            segment_session(partial, name, refined, progress=progress)
    return choice


def mask_choice(session: SessionReader, segmenter: str, chosen: bool = False) -> dict[str, Any]:
    """Which masks ``run`` uses: ``{"masks": "capture", …}`` when every training camera of ``session`` has
    masks from its capture (held-out ones without are scored against the training masks' hull), else
    ``{"masks": segmenter, …}`` (the capture's masks of some cameras are then replaced, and said so). A
    synthetic capture's ground-truth masks are never fitted on; a ``chosen`` segmenter (the user's) replaces
    the capture's masks in every camera."""
    reader = session.provenance.get("reader", {})
    shipped = [name for name in session.camera_names if session.has_source_mask(name)]
    training = [name for name in session.camera_names if name not in session.heldout]
    if not chosen and reader.get("ground_truth") and not reader.get("masks"):  # a synthetic capture's truth scores the run; it does not fit it
        return {"masks": segmenter, "cameras": list(session.camera_names),
                "detail": f"made by the {segmenter} segmenter for every camera (the capture's masks are its ground truth, {reader['ground_truth']})"}
    if not chosen and shipped and set(training) <= set(shipped):
        detail = f"the capture's own, of {', '.join(shipped)}"
        lacking = [name for name in session.camera_names if name not in shipped]
        if lacking:
            detail += f" (held out {', '.join(lacking)} has none: evaluated against the training masks' hull)"
        return {"masks": "capture", "cameras": shipped, "detail": detail}
    detail = f"made by the {segmenter} segmenter{' (--segmenter)' if chosen else ''} for every camera"
    if shipped:
        detail += f"; the capture's own masks of {', '.join(shipped)} are not used" + ("" if chosen else (
            f", as training camera(s) {', '.join(sorted(set(training) - set(shipped)))} have none"))
    return {"masks": segmenter, "cameras": list(session.camera_names), "detail": detail}
