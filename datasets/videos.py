"""The ``videos`` format: one video per calibrated camera plus an anipose or Pose2Sim calibration, or
EasyMocap's ``intri.yml`` + ``extri.yml``.

Layout: ``SOURCE/*.{mp4,avi,mov,mkv}`` or ``SOURCE/videos/*.{…}`` (the sub-folder wins when it has
videos), matched to the calibration's cameras by name (see :mod:`mmcsplat.datasets.rig`). The calibration
is the ``calibration`` argument, else ``SOURCE/calibration.toml``, else the single ``SOURCE/*.toml`` or
EasyMocap pair, else the same in ``SOURCE/calibration/`` (:func:`~mmcsplat.datasets.rig.find_calibration`);
a camera it states no image size for (EasyMocap's may not) takes its video's. A
``SOURCE/ground_truth.zarr`` (written by ``mmcsplat synth``) adds per-frame masks and depth. Masks the
capture brings: ``SOURCE/masks/<camera>/`` holds one mask image per frame, the k-th in natural order
(``0000.png``, ``0001.png``, …) being frame k; a camera with fewer masks than frames is an error.

Caliscope's ``timestamps.csv`` beside ``cam_N`` videos is checked: a camera that missed a moment the
others hold is refused (:mod:`mmcsplat.datasets.caliscope_timing`), since frame by frame it would be out of sync.

Frames are decoded lazily with OpenCV, one camera's decoder open at a time.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.datasets.caliscope_timing import check_caliscope_timing
from mmcsplat.datasets.frame_rate import DEFAULT_FPS
from mmcsplat.datasets.rig import (
    CAMERA_MAP_PARAMETER,
    CAMERAS_PARAMETER,
    MASKS_FOLDER,
    SIZE_MISMATCH_PARAMETER,
    TRIAL_PARAMETER,
    RigRecording,
    common_length,
    find_calibration,
    fit_camera,
    mask_folders,
)
from mmcsplat.plugin_api.errors import InputError, NotAFolderError
from mmcsplat.plugin_api.interfaces import Reader, RecordedFrame, Recording
from mmcsplat.plugin_api.parameters import parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import calibration_names, read_calibration
from mmcsplat.storage.camera_names import match_cameras

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")


#: The folders tried for videos, in order (module docstring).
VIDEO_FOLDERS = ("videos", "videos-raw", ".")


def _videos_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES) if folder.is_dir() else []


def video_files(source: Path) -> list[Path]:
    """The videos of ``source`` in the first layout that has any (module docstring). Per-camera folders are
    returned as the folders themselves (:func:`camera_video` finds the video inside)."""
    for folder in (source / name for name in VIDEO_FOLDERS):
        found = _videos_in(folder)
        if found:
            return found
    if source.is_dir():
        return sorted(folder for folder in source.iterdir() if folder.is_dir() and len(_videos_in(folder)) == 1)
    return []


def camera_video(path: Path) -> Path:
    """The video of a matched entry of :func:`video_files`: the file, or the one video in a camera's folder."""
    return _videos_in(path)[0] if path.is_dir() else path


@attrs.frozen
class VideoInfo:
    """What probing a video found: its frame count, frame rate and decoded size."""

    path: Path
    frames: int
    fps: float
    width: int
    height: int


def probe(path: Path) -> VideoInfo:
    """Open ``path`` and decode its first frame; an error naming the file when that fails."""
    import cv2

    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise InputError(f"video {path}: cannot be opened (not a video, or an unsupported codec)")
        ok, image = capture.read()
        if not ok or image is None:
            raise InputError(f"video {path}: cannot decode its first frame")
        frames = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        if frames <= 0:  # some containers do not state it: count by decoding
            frames = 1
            while capture.grab():
                frames += 1
        return VideoInfo(path, frames, float(capture.get(cv2.CAP_PROP_FPS)), image.shape[1], image.shape[0])
    finally:
        capture.release()


def check_decodes(path: Path) -> None:
    """Decode the whole video once with ffmpeg, stopping at the first decoder error, and refuse a damaged
    one naming its file and the frame it breaks at. OpenCV conceals decoder errors (a video corrupted in
    its middle decodes to smeared frames without a word), so this is the only place they show."""
    import subprocess

    import imageio_ffmpeg

    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-nostdin", "-v", "error", "-xerror", "-threads", "1", "-i", str(path),
               "-map", "0:v:0", "-f", "framecrc", "-"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        decoded = sum(1 for line in result.stdout.splitlines() if line and not line.startswith("#"))
        cause = next((line.strip() for line in result.stderr.splitlines() if line.strip()), f"ffmpeg exit status {result.returncode}")
        raise InputError(f"video {path}: damaged at frame {decoded} (the decoder reports: {cause}); re-export or re-copy it, "
                         f"or ingest the frames before it with --frames 0:{decoded}")


@attrs.frozen
class VideoReader(Reader):
    """Reads a folder of per-camera videos."""

    size_mismatch: str = SIZE_MISMATCH_PARAMETER
    camera_map: Mapping[str, str] | str | None = CAMERA_MAP_PARAMETER
    trial: str | None = TRIAL_PARAMETER
    cameras: tuple[str, ...] | None = CAMERAS_PARAMETER
    verify: bool = parameter(True, doc="decode each video once with ffmpeg first: a damaged one is an error naming the frame")

    def detect(self, source: Path) -> bool:
        return Path(source).is_dir() and bool(video_files(Path(source)))

    def open(self, source: Path, calibration: Path | None = None, units: str = "m") -> Recording:
        source = Path(source)
        if not source.is_dir():
            raise NotAFolderError(f"videos source {source} is not a folder")
        calibration = find_calibration(source, calibration)
        # Matched by name first: a calibration stating no image size takes its videos' (read_calibration's sizes).
        names = calibration_names(calibration, self.cameras)
        matched = match_cameras(names, video_files(source), "video", source, self.camera_map, trial=self.trial)
        paths = {name: camera_video(path) for name, path in matched.items()}
        infos = {name: probe(paths[name]) for name in names}
        check_caliscope_timing(paths, {name: info.frames for name, info in infos.items()})
        calibrated = read_calibration(calibration, units, names, {name: (info.width, info.height) for name, info in infos.items()})
        if self.verify:
            for camera in calibrated:
                check_decodes(paths[camera.name])
        cameras = [fit_camera(c, infos[c.name].width, infos[c.name].height, self.size_mismatch, f"video {paths[c.name]}") for c in calibrated]
        num_frames = common_length({name: info.frames for name, info in infos.items()}, "video", source)
        masks = mask_folders(source, calibrated, self.camera_map)
        short = {name: len(files) for name, files in masks.items() if len(files) < num_frames}
        if short:
            detail = ", ".join(f"{name}: {count}" for name, count in short.items())
            raise InputError(f"{source / MASKS_FOLDER}: fewer mask images than the {num_frames} frames ({detail}); give one per frame, in frame order")
        provenance = {
            "calibration": str(calibration),
            "units": units,
            "videos": {name: str(path) for name, path in paths.items()},
            "size_mismatch": self.size_mismatch,
            "masks": str(source / MASKS_FOLDER) if masks else None,
        }
        return VideoRecording(source, cameras, _frame_rate(infos, source), num_frames, provenance, paths,
                              {name: files[:num_frames] for name, files in masks.items()})


def _frame_rate(infos: Mapping[str, VideoInfo], source: Path) -> float:
    """The videos' common frame rate (camera name → probe): videos at different rates are refused, since
    frame t of each would be another moment; a video stating no rate is assumed at the others' (warned)."""
    rates = {name: info.fps for name, info in infos.items()}
    valid = [fps for fps in rates.values() if fps > 0 and np.isfinite(fps)]
    if not valid:
        warnings.warn(f"{source}: the videos state no frame rate; assuming {DEFAULT_FPS} fps", stacklevel=3)
        return DEFAULT_FPS
    detail = ", ".join(f"{name} {fps:g} fps" if fps > 0 and np.isfinite(fps) else f"{name} none stated" for name, fps in rates.items())
    if max(valid) - min(valid) > 1e-3 * max(valid):
        raise InputError(f"{source}: the cameras' videos have different frame rates ({detail}): frame by frame they would be out of "
                         "sync; re-encode them to one rate (or ingest the cameras of one rate with --cameras)")
    if len(valid) < len(rates):
        warnings.warn(f"{source}: not every video states its frame rate ({detail}); using {valid[0]:g} fps", stacklevel=3)
    return valid[0]


class VideoRecording(RigRecording):
    """Per-camera videos, decoded on demand."""

    def __init__(self, source: Path, cameras: Sequence[Camera], fps: float, num_frames: int, provenance: dict, paths: dict[str, Path],
                 masks: dict[str, list[Path]] | None = None) -> None:
        super().__init__(source, cameras, fps, num_frames, provenance, masks)
        self._paths = paths

    def _decode(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        import cv2

        if not indices:
            return
        path = self._paths[camera]
        capture = cv2.VideoCapture(str(path))
        try:
            if indices.start > 0:
                capture.set(cv2.CAP_PROP_POS_FRAMES, indices.start)
            position = indices.start
            for t in indices:
                while position < t:  # skip frames between steps without converting them
                    if not capture.grab():
                        raise InputError(f"video {path}: ends before frame {t}")
                    position += 1
                ok, image = capture.read()
                position += 1
                if not ok or image is None:
                    raise InputError(f"video {path}: cannot decode frame {t}")
                yield RecordedFrame(t=t, rgb=cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
        finally:
            capture.release()
