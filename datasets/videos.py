"""The ``videos`` format: one video per calibrated camera plus an anipose, Pose2Sim, Caliscope or Qualisys
calibration, or EasyMocap's ``intri.yml`` + ``extri.yml``.

Layout: ``SOURCE/*.{mp4,avi,mov,mkv}`` or ``SOURCE/videos/*.{…}`` (or anipose's ``videos-raw/``,
FreeMoCap's ``synchronized_videos/``; a sub-folder wins when it has videos), matched to the calibration's
cameras by name (see :mod:`mmcsplat.datasets.rig`). The calibration is the ``calibration`` argument, else
``SOURCE/calibration.toml``, else the single ``SOURCE/*.toml`` of cameras, ``*.qca.txt`` or EasyMocap pair,
else the same in ``SOURCE/calibration/`` (:func:`~mmcsplat.datasets.rig.find_calibration`);
a camera it states no image size for (EasyMocap's may not) takes its video's. A
``SOURCE/ground_truth.zarr`` (written by ``mmcsplat synth``) adds per-frame masks and depth. Masks the
capture brings: ``SOURCE/masks/<camera>/`` holds one mask image per frame, the k-th in natural order
(``0000.png``, ``0001.png``, …) being frame k; a camera with fewer masks than frames is an error.

An OpenCap session (``SOURCE/Videos/CamN/``, :mod:`mmcsplat.storage.opencap_session`) gives one trial's
synchronised video from each camera folder, named as the folder.

Caliscope's ``timestamps.csv`` beside ``cam_N`` videos places each video's frames at their moments
(:mod:`mmcsplat.datasets.caliscope_timing`): a camera that missed a moment the others hold would be out of
sync frame by frame, so it is refused, or with ``missing_frames="absent"`` (``mmcsplat ingest
--skip-missing``) lacks that frame while the rest stay in sync.

Frames are decoded lazily with OpenCV, one camera's decoder open at a time.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.datasets.caliscope_timing import caliscope_frames
from mmcsplat.datasets.frame_rate import DEFAULT_FPS
from mmcsplat.datasets.posed_images import MISSING_FRAMES_POLICIES
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
from mmcsplat.plugin_api.parameters import one_of, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS, calibration_names, read_rig
from mmcsplat.storage.camera_names import match_cameras
from mmcsplat.storage.opencap_session import is_opencap_session, opencap_videos

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")


#: The folders tried for videos, in order (module docstring): Pose2Sim's and EasyMocap's, anipose's,
#: FreeMoCap's, the capture's own.
VIDEO_FOLDERS = ("videos", "videos-raw", "synchronized_videos", ".")


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
    #: Degrees the file's rotation tag turns its frames by (a phone's upright video), which decoding applies.
    rotation: int = 0


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
        return VideoInfo(path, frames, float(capture.get(cv2.CAP_PROP_FPS)), image.shape[1], image.shape[0],
                         int(capture.get(cv2.CAP_PROP_ORIENTATION_META)) % 360)
    finally:
        capture.release()


def decoded_frames(path: Path) -> int:
    """Decode the whole video once with ffmpeg and return its frame count, stopping at the first decoder
    error: a damaged video is refused naming its file and the frame it breaks at. OpenCV conceals decoder
    errors (a video corrupted in its middle decodes to smeared frames without a word), so this is the only
    place they show; and the count is the frames themselves, where the count a container states (what
    :func:`probe` reads) may be an estimate from its duration, as Matroska's is."""
    import subprocess

    import imageio_ffmpeg

    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-nostdin", "-v", "error", "-xerror", "-threads", "1", "-i", str(path),
               "-map", "0:v:0", "-f", "framecrc", "-"]
    result = subprocess.run(command, capture_output=True, text=True)
    decoded = sum(1 for line in result.stdout.splitlines() if line and not line.startswith("#"))
    if result.returncode != 0:
        cause = next((line.strip() for line in result.stderr.splitlines() if line.strip()), f"ffmpeg exit status {result.returncode}")
        raise InputError(f"video {path}: damaged at frame {decoded} (the decoder reports: {cause}); re-export or re-copy it, "
                         f"or ingest the frames before it with --frames 0:{decoded}")
    return decoded


@attrs.frozen
class VideoReader(Reader):
    """Reads a folder of per-camera videos."""

    size_mismatch: str = SIZE_MISMATCH_PARAMETER
    camera_map: Mapping[str, str] | str | None = CAMERA_MAP_PARAMETER
    trial: str | None = TRIAL_PARAMETER
    cameras: tuple[str, ...] | None = CAMERAS_PARAMETER
    verify: bool = parameter(True, doc="decode each video once with ffmpeg first: a damaged one is an error naming the frame; its frames counted, not the container's estimate")
    missing_frames: str = parameter("error", doc="a moment a camera missed (Caliscope's timestamps.csv): error, or absent (that camera "
                                                 "lacks the frame, the others keep it)", validator=one_of(*MISSING_FRAMES_POLICIES))

    def detect(self, source: Path) -> bool:
        return Path(source).is_dir() and (bool(video_files(Path(source))) or is_opencap_session(Path(source)))

    def open(self, source: Path, calibration: Path | None = None, units: str = AUTO_UNITS) -> Recording:
        source = Path(source)
        if not source.is_dir():
            raise NotAFolderError(f"videos source {source} is not a folder")
        calibration = find_calibration(source, calibration)
        # Matched by name first: a calibration stating no image size takes its videos' (read_rig's sizes).
        names = calibration_names(calibration, self.cameras)
        if is_opencap_session(source):
            paths = opencap_videos(source, names, self.trial)
        else:
            matched = match_cameras(names, video_files(source), "video", source, self.camera_map, trial=self.trial)
            paths = {name: camera_video(path) for name, path in matched.items()}
        infos = {name: probe(paths[name]) for name in names}
        for info in infos.values():
            if info.rotation:  # a 180° turn keeps the size, so no size check would tell a calibration of the unturned frames
                warnings.warn(f"video {info.path}: its rotation tag turns its frames by {info.rotation}°; they are read turned, as players "
                              "and OpenCV show them (and calibrate them): a calibration made from the frames unturned would not fit them",
                              stacklevel=2)
        rig = read_rig(calibration, units, names, {name: (info.width, info.height) for name, info in infos.items()})
        calibrated = rig.cameras
        timing = caliscope_frames(paths, self.missing_frames)
        if self.verify:
            infos = {name: attrs.evolve(info, frames=decoded_frames(info.path)) for name, info in infos.items()}
        if timing:
            timing.check_frames(paths, {name: info.frames for name, info in infos.items()})
        cameras = [fit_camera(c, infos[c.name].width, infos[c.name].height, self.size_mismatch, f"video {paths[c.name]}") for c in calibrated]
        # Without Caliscope's timing frame k of every video is moment k.
        num_frames = len(timing.times) if timing else common_length({name: info.frames for name, info in infos.items()}, "video", source)
        placed = timing.placed if timing else {name: list(range(num_frames)) for name in names}
        masks = mask_folders(source, calibrated, self.camera_map)
        needed = {name: 1 + max((k for k in placed[name] if k is not None), default=-1) for name in masks}
        short = {name: len(files) for name, files in masks.items() if len(files) < needed[name]}
        if short:
            detail = ", ".join(f"{name}: {count} of {needed[name]}" for name, count in short.items())
            raise InputError(f"{source / MASKS_FOLDER}: fewer mask images than the frames ingested ({detail}); give one per frame, in frame order")
        provenance = {
            "calibration": str(calibration),
            "units": rig.units,
            "videos": {name: str(path) for name, path in paths.items()},
            "size_mismatch": self.size_mismatch,
            "masks": str(source / MASKS_FOLDER) if masks else None,
            "timestamps": str(timing.path) if timing else None,
        }
        return VideoRecording(source, cameras, _frame_rate(infos, source), num_frames, provenance, paths, placed,
                              {name: [None if k is None else files[k] for k in placed[name]] for name, files in masks.items()},
                              timing.times if timing else None)


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
    """Per-camera videos, decoded on demand; ``placed[camera][t]`` is the video frame of moment ``t``
    (``None`` where the camera missed it), ``times`` the moments' seconds where the recording states them."""

    def __init__(self, source: Path, cameras: Sequence[Camera], fps: float, num_frames: int, provenance: dict, paths: dict[str, Path],
                 placed: Mapping[str, Sequence[int | None]], masks: dict[str, list[Path | None]] | None = None,
                 times: np.ndarray | None = None) -> None:
        super().__init__(source, cameras, fps, num_frames, provenance, masks)
        self._paths = paths
        self._placed = placed
        self._times = times

    def frame_times(self) -> np.ndarray:
        """The seconds of each moment: the recording's clock where it states one (Caliscope's), else by the frame rate."""
        return super().frame_times() if self._times is None else self._times.copy()

    def present(self, camera: str) -> np.ndarray:
        """The moments this camera's video holds a frame of (all, unless Caliscope's timing says it missed some)."""
        return self.source_frames(camera) >= 0

    def source_frames(self, camera: str) -> np.ndarray:
        """Each moment's frame of this camera's video (−1 where it missed the moment)."""
        return np.array([-1 if k is None else k for k in self._placed[camera]], dtype=np.int64)

    def _decode(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        import cv2

        wanted = [(t, self._placed[camera][t]) for t in indices if self._placed[camera][t] is not None]
        if not wanted:
            return
        path = self._paths[camera]
        capture = cv2.VideoCapture(str(path))
        try:
            position = wanted[0][1]
            if position > 0:
                capture.set(cv2.CAP_PROP_POS_FRAMES, position)
            for t, k in wanted:
                while position < k:  # skip frames between steps without converting them
                    if not capture.grab():
                        raise InputError(f"video {path}: ends before frame {k}")
                    position += 1
                ok, image = capture.read()
                position += 1
                if not ok or image is None:
                    raise InputError(f"video {path}: cannot decode frame {k}")
                yield RecordedFrame(t=t, rgb=cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
        finally:
            capture.release()
