"""Ingest: turn a capture in any registered format into a session (see :mod:`mmcsplat.storage.session`).

The format's reader is found through the registry (named, or auto-detected with ``Reader.detect``).
Frames, masks and depth are undistorted with OpenCV — ``getOptimalNewCameraMatrix`` with ``alpha=0``
(only valid pixels, no black border) and ``initUndistortRectifyMap`` + ``remap``, linear for colour and
nearest for masks and depth; a fisheye camera through ``cv2.fisheye``'s
``estimateNewCameraMatrixForUndistortRectify`` with ``balance=0`` (the same: no border, the image's
periphery cropped) and its ``initUndistortRectifyMap`` — so the stored cameras are ideal pinholes with the new K; ``scale`` then
resizes the images (area averaging when shrinking) with K scaled to match (:meth:`Camera.scaled`).
Everything is written through :class:`~mmcsplat.storage.session.SessionWriter`, which commits atomically: a failed
or interrupted ingest leaves nothing that reads as a session.

Clean plates — one image per camera of the empty scene (the mat before the infant is laid on it), named
after the camera (``cam_0.png``) in a ``plates/`` folder of the capture or the folder given — are
undistorted like the frames and stored with the session, for fits that composite the subject over them
(``fit.background = "plate"``).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import attrs
import numpy as np

from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.pipeline.image_scale import checked_scale, resolve_scale
from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS
from mmcsplat.storage.capture_files import PLATES_FOLDER
from mmcsplat.storage.session.format import local_path

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import Reader, Recording
    from mmcsplat.storage.session import SessionReader


def parse_frames(text: str) -> slice:
    """``"START:STOP[:STEP]"`` (each part optional, e.g. ``"10:"`` or ``"::2"``) as a slice of frame indices."""
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise InputError(f"frames {text!r}: expected START:STOP[:STEP], e.g. 0:100 or 0:100:2")
    try:
        start, stop, step = (int(part) if part.strip() else None for part in (parts + [""])[:3])
    except ValueError:
        raise InputError(f"frames {text!r}: START, STOP and STEP must be whole numbers") from None
    if (start is not None and start < 0) or (stop is not None and stop < 0):
        raise InputError(f"frames {text!r}: START and STOP must not be negative")
    if step is not None and step <= 0:
        raise InputError(f"frames {text!r}: STEP must be positive")
    return slice(start, stop, step)


def capture_reader(source: Path, format: str | None = None, reader_options: Mapping[str, object] | None = None) -> tuple[str, Reader]:
    """(name, reader) of the registered reader ``format`` (else the one that recognises ``source``) made with
    ``reader_options``: an unknown or invalid option fails here, before anything is read or written."""
    registry = default_registry()
    name = format or detect_format(source, registry)
    return name, registry.create("reader", name, **(reader_options or {}))


def detect_format(source: Path, registry: Registry | None = None) -> str:
    """The one registered reader that recognises ``source``; a clear error when none or several do."""
    registry = registry or default_registry()
    matches, failures = [], []
    for name in registry.names("reader"):
        try:
            if registry.create("reader", name).detect(Path(source)):
                matches.append(name)
        except Exception as error:  # one broken reader must not hide the others
            failures.append(f"{name} ({error})")
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise InputError(f"{source}: several formats match ({', '.join(matches)}); choose one with --format")
    layouts = "; ".join(f"{name}: {registry.get('reader', name).registration.summary}" for name in registry.names("reader")) or "no reader is registered"
    broken = f"; readers that failed: {'; '.join(failures)}" if failures else ""
    raise InputError(f"{source}: no reader recognises this folder — the layouts known are {layouts}{broken}; is it empty or the wrong path?")


@attrs.frozen(eq=False)
class Undistorter:
    """Maps one camera's images into the stored (undistorted, rescaled) image space."""

    #: The stored camera: an ideal pinhole, the new K, rescaled.
    camera: Camera
    #: ``initUndistortRectifyMap``'s (map_x, map_y) at the original size, or None for an ideal pinhole.
    maps: tuple[np.ndarray, np.ndarray] | None

    @classmethod
    def for_camera(cls, camera: Camera, scale: float = 1.0) -> Undistorter:
        """The undistortion of ``camera`` followed by a resize by ``scale``."""
        import cv2

        size = (camera.width, camera.height)
        maps = None
        undistorted = camera
        if camera.fisheye:
            lens = camera.fisheye_coefficients
            new_K = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(camera.K, lens, size, np.eye(3), balance=0.0)
            maps = cv2.fisheye.initUndistortRectifyMap(camera.K, lens, np.eye(3), new_K, size, cv2.CV_32FC1)
            undistorted = attrs.evolve(camera, K=new_K)
        elif camera.is_distorted:
            new_K, _ = cv2.getOptimalNewCameraMatrix(camera.K, camera.distortion, size, 0.0, size)
            maps = cv2.initUndistortRectifyMap(camera.K, camera.distortion, None, new_K, size, cv2.CV_32FC1)
            undistorted = attrs.evolve(camera, K=new_K)
        undistorted = attrs.evolve(undistorted, distortion=[], fisheye=False)
        width, height = round(camera.width * scale), round(camera.height * scale)
        if width < 1 or height < 1:
            raise InputError(f"camera {camera.name!r}: scale {scale} leaves no pixels of its {camera.width}×{camera.height} images")
        if (width, height) != size:
            undistorted = undistorted.scaled(width / camera.width, height / camera.height)
        return cls(undistorted, maps)

    def _apply(self, image: np.ndarray, interpolation: int, shrink: int) -> np.ndarray:
        import cv2

        if self.maps is not None:
            image = cv2.remap(image, *self.maps, interpolation, borderMode=cv2.BORDER_REPLICATE)
        size = (self.camera.width, self.camera.height)
        if (image.shape[1], image.shape[0]) != size:
            smaller = size[0] < image.shape[1]
            image = cv2.resize(image, size, interpolation=shrink if smaller else interpolation)
        return image

    def rgb(self, image: np.ndarray) -> np.ndarray:
        """[H, W, 3] uint8 in the stored image space (linear sampling, area averaging when shrinking)."""
        import cv2

        return self._apply(image, cv2.INTER_LINEAR, cv2.INTER_AREA)

    def mask(self, mask: np.ndarray) -> np.ndarray:
        """[H, W] bool in the stored image space (nearest sampling)."""
        import cv2

        return self._apply(mask.astype(np.uint8), cv2.INTER_NEAREST, cv2.INTER_NEAREST) > 0

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """[H, W] float32 metres in the stored image space (nearest: depth is never blended across edges)."""
        import cv2

        return self._apply(depth.astype(np.float32), cv2.INTER_NEAREST, cv2.INTER_NEAREST)


PLATE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def read_plates(folder: Path, cameras: Sequence[Camera]) -> dict[str, np.ndarray]:
    """Each camera's clean plate from ``folder`` (``<camera name>.png``, .jpg, …) as [H, W, 3] uint8 at
    the camera's calibrated size; an error names the camera without a plate or the file of the wrong size."""
    from mmcsplat.storage.capture_files import read_image

    plates = {}
    for camera in cameras:
        path = next((path for suffix in PLATE_SUFFIXES if (path := folder / f"{camera.name}{suffix}").is_file()), None)
        if path is None:
            raise MissingFileError(f"plates {folder}: no plate for camera {camera.name!r} (expected {camera.name}.png or another image type)")
        rgb, _ = read_image(path)
        if rgb.shape[:2] != (camera.height, camera.width):
            raise InputError(f"plate {path}: {rgb.shape[1]}×{rgb.shape[0]} pixels, but camera {camera.name!r} is calibrated at {camera.width}×{camera.height}")
        plates[camera.name] = rgb
    return plates


def _select(cameras: Sequence[Camera], names: Sequence[str] | None, what: str) -> list[str]:
    """``names`` checked against ``cameras`` (all of them when ``names`` is None)."""
    known = [camera.name for camera in cameras]
    if names is None:
        return known
    unknown = [name for name in names if name not in known]
    if unknown:
        raise InputError(f"{what}: no camera named {', '.join(map(repr, unknown))}; cameras are {', '.join(known)}")
    return list(dict.fromkeys(names))


#: URL schemes whose data does not outlive the process that wrote it.
VOLATILE_SCHEMES = ("memory",)


def check_output(source: Path, out: str | os.PathLike) -> None:
    """Refuse a session output that would keep nothing, or that is the capture or contains it (replacing
    it would delete the recording)."""
    scheme = os.fspath(out).partition("://")[0] if "://" in os.fspath(out) else ""
    if scheme in VOLATILE_SCHEMES:
        raise InputError(f"{os.fspath(out)}: a {scheme}:// store keeps nothing after this process ends; write the session to a folder or a persistent URL")
    target = local_path(out)
    if target is not None and (target.resolve() == source or source.is_relative_to(target.resolve())):
        raise InputError(f"output {os.fspath(out)} is the capture {source} or contains it: write the session elsewhere")


def source_frame_offsets(recording: Recording, cameras: Sequence[str]) -> dict[str, list[list[int]]]:
    """For each of ``cameras`` whose own frame numbers (:meth:`~mmcsplat.plugin_api.interfaces.Recording.source_frames`)
    are not the frame indices, the runs ``[first frame index, offset]`` of its number minus the index over the
    frames it holds (a Caliscope camera one frame behind from its missed moment on: ``[[0, 0], [k + 1, -1]]``);
    what :meth:`~mmcsplat.storage.session.SessionReader.source_frames` reads back."""
    runs = {}
    for camera in cameras:
        numbers = np.asarray(recording.source_frames(camera), dtype=np.int64)
        held = np.flatnonzero(numbers >= 0)
        offsets = numbers[held] - held
        if offsets.any():
            starts = np.flatnonzero(np.diff(offsets, prepend=offsets[0] - 1))
            runs[camera] = [[int(held[i]), int(offsets[i])] for i in starts]
    return runs


def units_read(session: SessionReader) -> str:
    """The units ``session``'s calibration was read in, as its reader recorded them; metres for a reader that
    records none (poses without a unit of their own)."""
    return session.provenance.get("reader", {}).get("units", "m")


def units_chosen(session: SessionReader, units: str) -> str | None:
    """The units ``--units auto`` read ``session``'s calibration in where they were not metres (what ingest
    and ``run`` say, since the user did not); ``None`` otherwise."""
    read_in = units_read(session)
    return read_in if units == AUTO_UNITS and read_in != "m" else None


def ingest(
    source: Path,
    out: str | os.PathLike,
    *,
    format: str | None = None,
    calibration: Path | None = None,
    units: str = AUTO_UNITS,
    frames: slice | None = None,
    scale: float | str = 1.0,
    cameras: Sequence[str] | None = None,
    holdout: Sequence[str] = (),
    overwrite: bool = False,
    progress: bool = True,
    reader_options: dict | None = None,
    plates: Path | None = None,
    skip_missing: bool = False,
) -> SessionReader:
    """Read ``source`` (``format`` or auto-detected), undistort and rescale its frames, and write the
    session at ``out``; returns it opened for reading.

    ``frames`` selects frame indices, ``scale`` resizes the images (or ``"auto"``: :func:`~mmcsplat.pipeline.image_scale.resolve_scale`),
    ``cameras`` a subset of cameras (in that order), ``holdout`` cameras
    kept for evaluation (added to those the format itself holds out), ``reader_options`` parameters of
    the reader (e.g. ``{"size_mismatch": "crop"}`` for ``videos``), ``plates`` a folder of clean plates
    (default: the capture's ``plates/`` folder when it has one; every selected camera needs a plate),
    ``skip_missing`` ingests without the images the capture lists but lacks (the reader's
    ``missing_frames="absent"``). The session records ``source`` (and ``calibration``) as absolute paths.
    """
    from tqdm import tqdm

    from mmcsplat.storage.session import SessionReader, SessionWriter

    source = Path(source)
    if not source.exists():
        raise MissingFileError(f"source {source} does not exist")
    # Recorded absolute, so the session finds its capture (and ground truth) from any working directory.
    source = source.resolve()
    check_output(source, out)
    calibration = None if calibration is None else Path(calibration).resolve()
    checked_scale(scale)  # refused before anything is read
    name, reader = capture_reader(source, format, reader_options)
    if skip_missing:
        if not (attrs.has(type(reader)) and "missing_frames" in attrs.fields_dict(type(reader))):
            raise InputError(f"--skip-missing: the {name} reader has no missing_frames option: it lists no image files that could be missing")
        reader = attrs.evolve(reader, missing_frames="absent")
    outside = [camera for camera in holdout or () if cameras is not None and camera not in cameras]
    if outside:  # before the reader reads only the cameras asked for, which would not know these at all
        raise InputError(f"--holdout: {', '.join(outside)} not among the selected cameras {', '.join(cameras)}")
    if cameras is not None and attrs.has(type(reader)) and "cameras" in attrs.fields_dict(type(reader)):
        # A reader of a calibration reads and checks only the cameras asked for: a broken one left out stays out.
        reader = attrs.evolve(reader, cameras=tuple(cameras))
    recording = reader.open(source, calibration, units)
    try:
        selected = _select(recording.cameras, cameras, "--cameras")
        heldout = _select(recording.cameras, holdout, "--holdout")
        heldout += [c for c in recording.heldout if c in selected and c not in heldout]
        if len(heldout) == len(selected):
            raise InputError(f"every selected camera ({', '.join(selected)}) is held out: nothing is left to train on")
        indices = range(*(frames or slice(None)).indices(recording.num_frames))
        if not indices:
            raise InputError(f"the frames asked for select none of the {recording.num_frames} frames of {source}")
        if frames is not None and frames.stop is not None and frames.stop > recording.num_frames:
            warnings.warn(f"--frames {frames.start or ''}:{frames.stop}: {source} has {recording.num_frames} frames; taking frames "
                          f"{indices[0]}–{indices[-1]} ({len(indices)})", stacklevel=2)
        by_name = {camera.name: camera for camera in recording.cameras}
        plates_folder = Path(plates) if plates is not None else source / PLATES_FOLDER
        if plates is not None and not plates_folder.is_dir():
            raise MissingFileError(f"plates folder {plates_folder} does not exist")
        plate_images = read_plates(plates_folder, [by_name[camera] for camera in selected]) if plates_folder.is_dir() else {}
        scale = resolve_scale(scale, [by_name[camera] for camera in selected])
        undistorters = {camera: Undistorter.for_camera(by_name[camera], scale) for camera in selected}
        expected = {camera: int(recording.present(camera)[indices.start : indices.stop : indices.step].sum()) for camera in selected}
        provenance = {
            "format": name,
            "reader": recording.describe(),
            "units": units,
            "frames": [indices.start, indices.stop, indices.step],
            "scale": scale,
            "undistortion": "cv2.getOptimalNewCameraMatrix(alpha=0) + remap",
            # The cameras as recorded (distorted, in the decoded images' pixels): what maps a pixel of the
            # source videos — a 2D keypoint detected in them — into the stored images.
            "source_cameras": [by_name[camera].to_dict() for camera in selected],
            "plates": str(plates_folder.resolve()) if plate_images else None,
            # Where a camera's own frame numbers (its video's, which its 2D keypoints follow) are not the capture's.
            "source_frame_offsets": source_frame_offsets(recording, selected),
        }
        with SessionWriter(
            out,
            cameras=[undistorters[camera].camera for camera in selected],
            num_frames=len(indices),
            fps=recording.fps / indices.step,
            frame_times=recording.frame_times()[indices.start : indices.stop : indices.step],
            heldout=heldout,
            source=str(source),
            provenance=provenance,
            overwrite=overwrite,
        ) as writer, tqdm(total=sum(expected.values()), unit="frame", desc=f"ingest {source.name}", disable=not progress) as bar:
            for camera in selected:
                undistort, written = undistorters[camera], 0
                if camera in plate_images:
                    writer.write_plate(camera, undistort.rgb(plate_images[camera]))
                for frame in recording.frames(camera, indices):
                    writer.write_frame(
                        camera,
                        (frame.t - indices.start) // indices.step,
                        undistort.rgb(frame.rgb),
                        mask=None if frame.mask is None else undistort.mask(frame.mask),
                        depth=None if frame.depth is None else undistort.depth(frame.depth),
                    )
                    written += 1
                    bar.update()
                if written != expected[camera]:
                    raise InputError(f"camera {camera!r}: the {name} reader yielded {written} of {expected[camera]} frames of {source}")
            writer.commit()
    finally:
        recording.close()
    return SessionReader(out)
