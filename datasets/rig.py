"""What the readers of real-rig layouts (``videos``, ``images``) share: finding the calibration,
reconciling decoded image sizes and frame counts, subject masks shipped with the capture (a ``masks/``
folder per camera), and the optional ``ground_truth.zarr`` the synthetic capture writes next to its videos. Files are matched to calibrated cameras by
:func:`mmcsplat.storage.camera_names.match_cameras`.
"""

from __future__ import annotations

import warnings
from abc import abstractmethod
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import RecordedFrame, Recording
from mmcsplat.plugin_api.parameters import one_of, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import is_camera_toml
from mmcsplat.storage.camera_names import match_cameras, natural_key
from mmcsplat.storage.capture_files import read_mask
from mmcsplat.storage.easymocap_calibration import easymocap_files
from mmcsplat.storage.ground_truth import GROUND_TRUTH, GroundTruthReader
from mmcsplat.storage.opencap_calibration import OPENCAP_CALIBRATION, opencap_files
from mmcsplat.storage.opencap_session import SESSION_VIDEOS
from mmcsplat.storage.qualisys_calibration import is_qualisys

#: How a decoded size that differs from the calibration's is reconciled (see :func:`fit_camera`).
SIZE_MISMATCH_POLICIES = ("scale", "crop", "error")
#: Above this relative difference between the horizontal and vertical factors, scaling K makes no sense.
MAX_ANISOTROPY = 0.05
#: Where a capture keeps its own subject masks: ``SOURCE/masks/<camera>/`` (see :func:`mask_folders`).
MASKS_FOLDER = "masks"
MASK_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


#: Where a rig's calibration is looked for, in order, under the source folder (:func:`calibration_candidates`).
#: ``calibration/`` is where Pose2Sim (``Calib_*.toml``) and anipose (``calibration.toml``) projects keep
#: it; EasyMocap and ZJU-MoCap keep ``intri.yml`` and ``extri.yml`` at the capture's root.
CALIBRATION_FOLDERS = (".", "calibration")
#: Pose2Sim's project file. In its batch layout each trial is a folder holding one beside the session's
#: own, and the trials share the session's ``calibration/`` folder.
POSE2SIM_CONFIG = "Config.toml"


def calibration_candidates(folder: Path) -> list[Path]:
    """The calibrations ``folder`` holds: its ``calibration.toml`` alone if it has one, else its ``*.toml``
    files that hold cameras (not a Pose2Sim project's ``Config.toml``), its Qualisys ``*.qca.txt`` files, its
    EasyMocap pair (as the pair's ``intri.yml``) and the OpenCap files of its camera folders, or of an OpenCap
    session's (in its ``Videos/``), as the first camera's."""
    default = folder / "calibration.toml"
    if default.is_file():
        return [default]
    pair = easymocap_files(folder)
    found = [path for path in folder.glob("*.toml") if is_camera_toml(path)] + [path for path in folder.glob("*") if is_qualisys(path)]
    return sorted(found) + ([pair[0]] if pair and all(path.is_file() for path in pair) else []) + (opencap_files(folder) or opencap_files(folder / SESSION_VIDEOS))[:1]


def find_calibration(source: Path, calibration: Path | None) -> Path:
    """``calibration`` when given (a folder: its one calibration; either EasyMocap file stands for the
    pair, as its ``intri.yml``; one OpenCap camera's file, the rig), else the one calibration of ``source``, else of
    ``source/calibration/``, else, for a trial of a Pose2Sim batch (:data:`POSE2SIM_CONFIG` in it and in its parent), of the
    session's ``calibration/``."""
    if calibration is None:
        folders = [source / name for name in CALIBRATION_FOLDERS]
        if (source / POSE2SIM_CONFIG).is_file() and (source.parent / POSE2SIM_CONFIG).is_file():
            folders.append(source.parent / "calibration")
    else:
        calibration = Path(calibration)
        if not calibration.is_dir():
            pair = easymocap_files(calibration)
            for path in pair or (calibration,):
                if not path.is_file():
                    raise MissingFileError(f"calibration file {path} does not exist")
            return pair[0] if pair else calibration
        folders = [calibration]
    for folder in folders:
        candidates = calibration_candidates(folder)
        if len(candidates) == 1:
            return candidates[0]
        if candidates:
            names = ", ".join(path.name for path in candidates)
            qualisys = [path.name for path in candidates if is_qualisys(path)]
            hint = (f" (Pose2Sim's conversion of {qualisys[0]} to TOML divides its lens distortion by 64: the .qca.txt holds the lens as "
                    "Qualisys calibrated it, docs/ingest.md)") if qualisys and len(qualisys) < len(candidates) else ""
            raise InputError(f"{folder}: several calibration files ({names}); choose one with --calibration{hint}")
    looked_for = ("no calibration.toml, other single *.toml of cameras, Qualisys *.qca.txt, EasyMocap intri.yml + extri.yml, "
                  f"or OpenCap camera folders' {OPENCAP_CALIBRATION}")
    if calibration is not None:
        raise MissingFileError(f"calibration folder {calibration}: {looked_for} in it")
    raise MissingFileError(f"{source}: {looked_for} in it or in its calibration/ folder; pass --calibration")


#: The ``camera_map`` parameter of the readers that match files to calibrated cameras.
CAMERA_MAP_PARAMETER = parameter(None, doc="calibration camera name → its file's or folder's name, where the names differ; or "
                                             "\"order\": the calibration's cameras, in its order, to the files in name order")
#: The ``trial`` parameter of the readers (and keypoint sources) that match one file per camera by name.
TRIAL_PARAMETER = parameter(None, doc="read only the files whose name starts with this: one trial of several side by side "
                                      "(anipose's vid01-camA.avi beside vid02-camA.avi: trial=\"vid01\")")
#: The ``cameras`` parameter of the readers that read a calibration: ingest's ``--cameras`` sets it, so a
#: broken camera left out of the calibration (a copied table) is never read or checked.
CAMERAS_PARAMETER = parameter(None, doc="only these calibrated cameras are read and checked (mmcsplat ingest/run --cameras sets it)",
                              converter=lambda names: None if names is None else tuple(names))
#: The ``size_mismatch`` parameter of the readers that decode images against a calibration.
SIZE_MISMATCH_PARAMETER = parameter("scale", doc="a decoded size unlike the calibration's: scale K, crop, or error (fit_camera)",
                                    validator=one_of(*SIZE_MISMATCH_POLICIES))


def fit_camera(camera: Camera, width: int, height: int, policy: str, what: str) -> Camera:
    """``camera`` made consistent with images decoded at ``width``×``height``, with a warning if it changed.

    ``"scale"`` scales K by the size ratios (the images were resampled; an error when the two ratios differ
    by more than ``MAX_ANISOTROPY``, e.g. a rotated video); ``"crop"`` keeps K and takes the images as the
    top-left part of the calibrated frame; ``"error"`` refuses.
    """
    if policy not in SIZE_MISMATCH_POLICIES:
        raise InputError(f"unknown size_mismatch policy {policy!r}; choose one of {', '.join(SIZE_MISMATCH_POLICIES)}")
    if (width, height) == (camera.width, camera.height):
        return camera
    mismatch = f"{what} decodes at {width}×{height} but camera {camera.name!r} is calibrated at {camera.width}×{camera.height}"
    if policy == "error":
        raise InputError(f"{mismatch} (size_mismatch='error')")
    if policy == "crop":
        if width > camera.width or height > camera.height:
            raise InputError(f"{mismatch}: larger than calibrated, so it cannot be a crop")
        warnings.warn(f"{mismatch}; keeping K and treating the images as the top-left crop (size_mismatch='crop')", stacklevel=3)
        return attrs.evolve(camera, width=width, height=height)
    sx, sy = width / camera.width, height / camera.height
    if abs(sx / sy - 1.0) > MAX_ANISOTROPY:
        raise InputError(f"{mismatch}: the aspect ratio differs too much to rescale K (rotated or wrong file?)")
    warnings.warn(f"{mismatch}; scaling K by ({sx:.5f}, {sy:.5f}) to match (size_mismatch='scale')", stacklevel=3)
    return camera.scaled(sx, sy)


def mask_folders(source: Path, cameras: Sequence[Camera], camera_map: Mapping[str, str] | str | None) -> dict[str, list[Path]]:
    """Each camera's mask images (natural order) in ``SOURCE/masks/<camera>/``, the folders matched to the
    cameras by name like videos; empty when the capture has no ``masks/`` folder. With one, every camera
    needs its folder (an error names the camera without one)."""
    root = source / MASKS_FOLDER
    if not root.is_dir():
        return {}
    folders = match_cameras([camera.name for camera in cameras], sorted(path for path in root.iterdir() if path.is_dir()), "mask folder", root,
                            camera_map)
    return {name: sorted((path for path in folder.iterdir() if path.is_file() and path.suffix.lower() in MASK_SUFFIXES),
                         key=lambda path: natural_key(path.name)) for name, folder in folders.items()}


def common_length(counts: Mapping[str, int], what: str, where: Path) -> int:
    """The shortest of the cameras' frame counts, with a warning when they differ."""
    shortest = min(counts.values())
    if shortest <= 0:
        empty = ", ".join(name for name, count in counts.items() if count <= 0)
        raise InputError(f"{where}: no frames in the {what}s of {empty}")
    if max(counts.values()) != shortest:
        detail = ", ".join(f"{name}: {count}" for name, count in counts.items())
        warnings.warn(f"{where}: {what}s differ in length ({detail}); truncating every camera to {shortest} frames", stacklevel=3)
    return shortest


@attrs.frozen(eq=False)
class GroundTruth:
    """Per-camera masks [T, H, W] uint8 and depth [T, H, W] metres of a ``ground_truth.zarr`` group, read
    one frame at a time."""

    path: Path
    masks: Mapping[str, object]
    depth: Mapping[str, object]

    @classmethod
    def open(cls, source: Path, cameras: Sequence[Camera], num_frames: int, images: Mapping[str, str]) -> GroundTruth | None:
        """The ground truth beside the capture, or ``None`` when there is none; errors name what is wrong,
        with the camera's images (``images``: camera name → its video or image folder)."""
        path = source / GROUND_TRUTH
        if not path.exists():
            return None
        group = GroundTruthReader(path).group
        fields: dict[str, dict[str, object]] = {}
        for field in ("masks", "depth"):
            if field not in group:
                fields[field] = {}
                continue
            arrays = {}
            for camera in cameras:
                if camera.name not in group[field]:
                    raise InputError(f"{path}: {field} has no array for camera {camera.name!r}")
                array = group[field][camera.name]
                frames, (height, width) = array.shape[0], array.shape[1:3]
                where = f"{path}: the {field} of camera {camera.name!r}"
                if (height, width) != (camera.height, camera.width):
                    raise InputError(f"{where} are {width}×{height} pixels but its {images.get(camera.name, 'images')} decodes at "
                                     f"{camera.width}×{camera.height}: the ground truth belongs to other videos — put back the videos "
                                     f"`mmcsplat synth` wrote (or synthesize the capture again), or move {GROUND_TRUTH} away to ingest "
                                     "without ground truth")
                if frames < num_frames:
                    raise InputError(f"{where} hold {frames} frames but its {images.get(camera.name, 'images')} has {num_frames}: "
                                     f"ingest the first {frames} with --frames 0:{frames}, or move {GROUND_TRUTH} away")
                arrays[camera.name] = array
            fields[field] = arrays
        return cls(path, fields["masks"], fields["depth"])

    def attach(self, camera: str, frame: RecordedFrame) -> RecordedFrame:
        """``frame`` with its mask and depth."""
        mask = np.asarray(self.masks[camera][frame.t]) > 0 if self.masks else None
        depth = np.asarray(self.depth[camera][frame.t], dtype=np.float32) if self.depth else None
        return attrs.evolve(frame, mask=mask, depth=depth)


class RigRecording(Recording):
    """A capture of calibrated cameras whose frames a subclass decodes; adds the capture's own masks
    (``masks[camera][t]``, a file per frame) and the ground truth if any."""

    def __init__(self, source: Path, cameras: Sequence[Camera], fps: float, num_frames: int, provenance: dict,
                 masks: Mapping[str, Sequence[Path | None]] | None = None) -> None:
        self.cameras = tuple(cameras)
        self.fps = fps
        self.num_frames = num_frames
        self._provenance = provenance
        self._masks = dict(masks or {})
        images = {**{name: f"video {path}" for name, path in provenance.get("videos", {}).items()},
                  **{name: f"image folder {path}" for name, path in provenance.get("folders", {}).items()}}
        self._ground_truth = GroundTruth.open(source, self.cameras, num_frames, images)
        self.has_masks = bool(self._masks) or bool(self._ground_truth and self._ground_truth.masks)
        self.has_depth = bool(self._ground_truth and self._ground_truth.depth)

    @abstractmethod
    def _decode(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        """Yield the decoded rgb frames of ``camera`` at ``indices``."""

    def frames(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        """Decoded frames of ``camera`` at ``indices``, checked against its size, with the ground truth."""
        expected = next((c for c in self.cameras if c.name == camera), None)
        if expected is None:
            raise KeyError(f"no camera {camera!r} in this recording")
        if indices and (min(indices) < 0 or max(indices) >= self.num_frames):
            raise IndexError(f"frames {indices.start}:{indices.stop}:{indices.step} exceed the recording's {self.num_frames}")
        for frame in self._decode(camera, indices):
            if frame.rgb.shape != (expected.height, expected.width, 3):
                raise InputError(
                    f"camera {camera!r} frame {frame.t}: decoded shape {frame.rgb.shape}, expected "
                    f"({expected.height}, {expected.width}, 3) like its first frame"
                )
            frame = self._ground_truth.attach(camera, frame) if self._ground_truth else frame
            path = self._masks[camera][frame.t] if camera in self._masks else None
            if path is not None:
                mask = read_mask(path)
                if mask.shape != frame.rgb.shape[:2]:
                    raise InputError(f"mask {path} is {mask.shape[1]}×{mask.shape[0]}, but camera {camera!r}'s frames are "
                                     f"{frame.rgb.shape[1]}×{frame.rgb.shape[0]}: give its masks at the size of its images")
                frame = attrs.evolve(frame, mask=mask)
            yield frame

    def describe(self) -> dict:
        """The reader's provenance, with the ground truth's path where the capture has one (its masks are
        the truth to score against, not masks the capture brings: ``mmcsplat run`` does not fit on them)."""
        truth = {"ground_truth": str(self._ground_truth.path),
                 "ground_truth_identity": GroundTruthReader(self._ground_truth.path).identity} if self._ground_truth else {}
        return {**self._provenance, **truth}
