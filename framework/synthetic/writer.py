"""Writing a synthetic capture: per-camera videos, calibration.toml and ground_truth.zarr, assembled in a
hidden temporary folder beside the output and moved into place only when complete."""

from __future__ import annotations

import glob
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import OutputExistsError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import remove_local_tree
from mmcsplat.storage.ground_truth import GROUND_TRUTH
from mmcsplat.storage.locking import WriterLock
from mmcsplat.synthetic.scene import Image

VIDEOS = "videos"
CALIBRATION = "calibration.toml"
PLATES = "plates"
#: Everything a synthetic capture folder holds: ``--overwrite`` replaces only such a folder.
CAPTURE_ENTRIES = frozenset({VIDEOS, CALIBRATION, GROUND_TRUTH, PLATES})
#: Lossless H.264 in RGB (4:4:4): the videos hold exactly the rendered frames. Measured on the default
#: capture, OpenCV's 'mp4v' reached 30 dB PSNR (26 dB inside the infant) and even lossless 4:2:0 H.264
#: only 27 dB inside the infant, because chroma subsampling smears the small coloured patterns.
VIDEO_CODEC = "libx264rgb"


class VideoStream:
    """One camera's video, encoded frame by frame by imageio-ffmpeg's ffmpeg."""

    def __init__(self, path: Path, width: int, height: int, fps: float) -> None:
        import imageio_ffmpeg

        self.path = path
        self._encoder = imageio_ffmpeg.write_frames(
            str(path), (width, height), fps=fps, codec=VIDEO_CODEC, pix_fmt_in="rgb24", pix_fmt_out="rgb24",
            quality=None, output_params=["-qp", "0", "-preset", "fast"], macro_block_size=1, ffmpeg_log_level="error",
        )  # fmt: skip
        self._encoder.send(None)

    def write(self, rgb: np.ndarray) -> None:
        """Append one frame [H, W, 3] uint8 RGB."""
        self._encoder.send(np.ascontiguousarray(rgb))

    def close(self) -> None:
        """Finish the file."""
        self._encoder.close()


def check_video(path: Path, frames: int, width: int, height: int) -> None:
    """Raise ``RuntimeError`` naming ``path`` unless OpenCV decodes it with ``frames`` frames of
    ``width`` × ``height``."""
    import cv2

    capture = cv2.VideoCapture(str(path))
    try:
        ok, image = capture.read()
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        capture.release()
    if not ok or image.shape[:2] != (height, width) or count != frames:
        found = f"{count} frames of {image.shape[1]}×{image.shape[0]}" if ok else "no decodable frame"
        raise RuntimeError(f"video {path}: OpenCV decodes {found}, expected {frames} frames of {width}×{height}")


class CaptureWriter:
    """Streams a capture to disk frame by frame. Use as a context manager: on an error (or interrupt) the
    temporary folder is removed; :meth:`commit` moves the finished capture to ``out_dir``."""

    def __init__(self, out_dir: Path, cameras: Sequence[Camera], num_frames: int, fps: float, overwrite: bool = False) -> None:
        self.out_dir = Path(out_dir)
        self.overwrite = overwrite
        check_output(self.out_dir, overwrite)
        self.out_dir.parent.mkdir(parents=True, exist_ok=True)
        self._lock = WriterLock(self.out_dir.parent / f".{self.out_dir.name}.lock", f"capture {self.out_dir}")
        for pattern in (".partial", ".old"):  # what a killed writer of this capture left (the lock is ours: none is running)
            for leftover in self.out_dir.parent.glob(f".{glob.escape(self.out_dir.name)}.*{pattern}"):
                remove_local_tree(leftover)
        self.cameras = list(cameras)
        self.num_frames = num_frames
        self.streams: list[VideoStream] = []
        self.temp = Path(tempfile.mkdtemp(prefix=f".{self.out_dir.name}.", suffix=".partial", dir=self.out_dir.parent))
        try:
            self._open(fps)
        except BaseException:  # no `with` will call abort: the folder and the lock go here
            self.abort()
            raise

    def _open(self, fps: float) -> None:
        """The encoders and the ground truth's arrays, in the temporary folder."""
        import zarr

        num_frames = self.num_frames
        self.temp.chmod(0o755)  # mkdtemp makes it private; the finished capture is an ordinary folder
        (self.temp / VIDEOS).mkdir()
        for camera in self.cameras:
            self.streams.append(VideoStream(self.temp / VIDEOS / f"{camera.name}.mp4", camera.width, camera.height, fps))
        self.group = zarr.open_group(str(self.temp / GROUND_TRUTH), mode="w-", zarr_format=3)
        masks, depth = self.group.create_group("masks"), self.group.create_group("depth")
        self.masks, self.depth = [], []  # per camera, one frame per chunk
        for camera in self.cameras:
            shape, chunks = (num_frames, camera.height, camera.width), (1, camera.height, camera.width)
            self.masks.append(masks.create_array(camera.name, shape=shape, chunks=chunks, dtype="uint8", fill_value=0))
            self.depth.append(depth.create_array(camera.name, shape=shape, chunks=chunks, dtype="float16", fill_value=0.0))

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(self, kind: type | None, error: BaseException | None, traceback: Any) -> None:
        if kind is not None:
            self.abort()

    def write_array(self, name: str, values: np.ndarray, attributes: dict[str, Any]) -> None:
        """A whole ground-truth array (e.g. ``surface_points`` [T, P, 3]) chunked by up to 64 frames."""
        chunks = (min(64, values.shape[0]), *values.shape[1:])
        array = self.group.create_array(name, shape=values.shape, chunks=chunks, dtype=values.dtype)
        array[...] = values
        array.attrs.update(attributes)

    def write_frame(self, t: int, camera: int, image: Image) -> None:
        """Frame ``t`` of camera number ``camera``: its video frame, mask and depth."""
        self.streams[camera].write(image.rgb)
        self.masks[camera][t] = image.mask
        self.depth[camera][t] = image.depth.astype(np.float16)

    def write_plate(self, camera: int, rgb: np.ndarray) -> None:
        """Camera number ``camera``'s clean plate, ``plates/<camera>.png`` (what ingest reads)."""
        import cv2

        folder = self.temp / PLATES
        folder.mkdir(exist_ok=True)
        path = folder / f"{self.cameras[camera].name}.png"
        if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise RuntimeError(f"plate {path}: OpenCV could not write it")

    def commit(self, attributes: dict[str, Any], calibration_metadata: dict[str, Any]) -> None:
        """Finish the videos and check that they decode, write the calibration and the ground truth's
        attributes, then move the capture to ``out_dir`` (replacing an old one only with ``overwrite``)."""
        from mmcsplat.storage.calibration import write_calibration

        for stream, camera in zip(self.streams, self.cameras):
            stream.close()
            check_video(stream.path, self.num_frames, camera.width, camera.height)
        self.streams = []
        write_calibration(self.temp / CALIBRATION, self.cameras, metadata=calibration_metadata)
        self.group.attrs.update(attributes)
        check_output(self.out_dir, self.overwrite)  # again: something may have appeared meanwhile
        old = None
        if self.out_dir.exists():
            old = self.out_dir.with_name(f".{self.out_dir.name}.{self.temp.name}.old")
            self.out_dir.rename(old)
        self.temp.rename(self.out_dir)
        if old is not None:
            remove_local_tree(old)
        self._lock.release()

    def abort(self) -> None:
        """Stop the encoders and remove the temporary folder."""
        for stream in self.streams:
            try:
                stream.close()
            except Exception:  # an encoder that already failed; its output is deleted below anyway
                pass
        self.streams = []
        shutil.rmtree(self.temp, ignore_errors=True)
        self._lock.release()


def check_output(out_dir: Path, overwrite: bool) -> None:
    """Refuse to replace an existing non-empty ``out_dir`` unless ``overwrite``, and even then anything but
    a synthetic capture (a folder of only what :class:`CaptureWriter` writes): nothing else is deleted."""
    if not out_dir.exists() and not out_dir.is_symlink():
        return
    if not out_dir.is_dir() or out_dir.is_symlink():
        what = "is not a folder" if not out_dir.is_symlink() else "is a link"
        raise OutputExistsError(f"output {out_dir} exists and {what}; --overwrite replaces only a synthetic capture, never other files")
    entries = sorted(path.name for path in out_dir.iterdir())
    if entries and not overwrite:
        raise OutputExistsError(f"output {out_dir} exists and is not empty; pass --overwrite to replace it")
    foreign = [name for name in entries if name not in CAPTURE_ENTRIES]
    if entries and (foreign or GROUND_TRUTH not in entries):
        shown = ", ".join(foreign[:5]) + (" …" if len(foreign) > 5 else "") if foreign else f"no {GROUND_TRUTH}"
        raise OutputExistsError(f"output {out_dir} is not a capture `mmcsplat synth` wrote ({shown}): --overwrite replaces only a "
                                "synthetic capture, never other files; give a new folder")
