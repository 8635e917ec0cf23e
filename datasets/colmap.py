"""A COLMAP sparse model plus its images: ``SOURCE/sparse/0/`` (or ``SOURCE/sparse/``) holding
``cameras.{bin,txt}`` and ``images.{bin,txt}``, and the images in ``SOURCE/images/``. ``points3D`` is not
read. When both the binary and the text model are present, the binary one (COLMAP's default output) is read.

Both model formats are parsed here by hand: pycolmap is a large compiled dependency that is not installed,
and the two files read are small fixed layouts. Text: ``cameras.txt`` lines ``CAMERA_ID MODEL WIDTH HEIGHT
PARAMS…``; ``images.txt`` lines ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME``, each followed by a line of
2D points (ignored, possibly empty); ``#`` lines are comments. Binary (little-endian): ``cameras.bin`` is
a uint64 count, then per camera int32 id, int32 model id, uint64 width, uint64 height and float64
parameters; ``images.bin`` a uint64 count, then per image int32 id, 4 float64 qvec, 3 float64 tvec, int32
camera id, the NUL-terminated name, a uint64 count of 2D points and that many (float64 x, float64 y,
int64 point3D id).

Conventions applied:

- Camera models: SIMPLE_PINHOLE (f cx cy), PINHOLE (fx fy cx cy), SIMPLE_RADIAL (f cx cy k), RADIAL
  (f cx cy k1 k2) and OPENCV (fx fy cx cy k1 k2 p1 p2), whose distortion is OpenCV's (k1, k2, p1, p2)
  with the missing terms zero (none when all are zero); OPENCV_FISHEYE (fx fy cx cy k1 k2 k3 k4),
  RADIAL_FISHEYE (f cx cy k1 k2) and SIMPLE_RADIAL_FISHEYE (f cx cy k), which are OpenCV's fisheye model
  (θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)) with the missing terms zero. Other models (FULL_OPENCV, FOV,
  thin prism) are refused, naming the model.
- Principal point: COLMAP's image coordinates have the image's top-left corner at (0, 0), so the centre
  of the top-left pixel is (0.5, 0.5); mmcsplat's pixel (u, v) is centred at (u, v)
  (:func:`mmcsplat.scene.camera.resize_matrix`), so cx and cy are read minus 0.5.
- Poses: ``qvec`` (w, x, y, z) and ``tvec`` are world-to-camera with OpenCV axes (x right, y down,
  looking along +z), as mmcsplat's; ``units`` scales the translations (COLMAP's scale is arbitrary
  unless the model was geo-registered).
- Layout (the ``layout`` parameter):

  - ``static``: a still scene: one frame, and one camera per registered image, named after the
    image's file stem (or its path under ``images/`` with ``/`` as ``_`` when stems repeat).
  - ``video``: a fixed rig filmed over time: registered image names are ``CAM/FILE``, each folder
    ``images/CAM/`` is one camera named ``CAM``, posed by its registered image(s) (several must agree on
    pose and COLMAP camera), and every image of the folder is a frame, matched across cameras by the
    number in its file name as in the ``images`` format (a gap is an error). Folders without a
    registered image are left out with a warning. ``fps`` gives the frame rate.
  - ``auto`` (default): ``video`` when every registered image name is ``CAM/FILE``, else ``static``.

- Images listed in the model must exist (an error lists every missing one), or with
  ``missing_frames="absent"`` are skipped: a static camera without its image is left out, a video
  layout's gap is a frame the camera lacks (:mod:`mmcsplat.datasets.posed_images`). Images in ``images/``
  the model does not list are ignored (except as frames of the video layout). There are no masks and no
  held-out cameras.
"""

from __future__ import annotations

import struct
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.datasets.frame_rate import FPS_PARAMETER, stated_or_assumed
from mmcsplat.datasets.images import frames_by_number, image_files
from mmcsplat.datasets.nerfstudio import PIXEL_CENTRE
from mmcsplat.datasets.posed_images import MISSING_FRAMES_PARAMETER, PosedImage, PosedImageRecording, missing_files
from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import Reader
from mmcsplat.plugin_api.parameters import one_of, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS, metres_per_unit

#: The supported camera models and their number of parameters.
MODEL_PARAMETERS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8,
                    "OPENCV_FISHEYE": 8, "SIMPLE_RADIAL_FISHEYE": 4, "RADIAL_FISHEYE": 5}
#: The supported models that are OpenCV's fisheye model.
FISHEYE_MODELS = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE")
#: COLMAP's model ids (the binary model's), supported or not.
MODEL_IDS = {0: "SIMPLE_PINHOLE", 1: "PINHOLE", 2: "SIMPLE_RADIAL", 3: "RADIAL", 4: "OPENCV", 5: "OPENCV_FISHEYE", 6: "FULL_OPENCV",
             7: "FOV", 8: "SIMPLE_RADIAL_FISHEYE", 9: "RADIAL_FISHEYE", 10: "THIN_PRISM_FISHEYE", 11: "RAD_TAN_THIN_PRISM_FISHEYE"}
LAYOUTS = ("auto", "static", "video")


@attrs.frozen
class ColmapCamera:
    """One entry of ``cameras.{txt,bin}``: its model, size and parameters as COLMAP stores them."""

    id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@attrs.frozen
class ColmapImage:
    """One entry of ``images.{txt,bin}``: the world-to-camera rotation (w, x, y, z) and translation, its
    camera id and its name relative to ``images/``."""

    id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int
    name: str


def model_folder(source: Path) -> Path | None:
    """``source/sparse/0`` or ``source/sparse``, whichever holds a cameras and an images file, or None."""
    for folder in (source / "sparse" / "0", source / "sparse"):
        if any((folder / f"cameras{ext}").is_file() and (folder / f"images{ext}").is_file() for ext in (".bin", ".txt")):
            return folder
    return None


@attrs.frozen
class ColmapReader(Reader):
    """Reads a COLMAP sparse model and its ``images/`` folder (layout and frame rate as parameters)."""

    layout: str = parameter("auto", doc="static (one frame, a camera per image), video (a camera per images/ sub-folder) or auto",
                            validator=one_of(*LAYOUTS))
    fps: float | None = FPS_PARAMETER
    missing_frames: str = MISSING_FRAMES_PARAMETER

    def detect(self, source: Path) -> bool:
        """A folder with ``images/`` and a sparse model in ``sparse/0/`` or ``sparse/``."""
        source = Path(source)
        return (source / "images").is_dir() and model_folder(source) is not None

    def open(self, source: Path, calibration: Path | None = None, units: str = AUTO_UNITS) -> PosedImageRecording:
        """Parse the model and check that every image it lists exists. ``units`` is the unit of the model's
        translations (``auto``: metres, as they stand); a separate calibration is refused (the model gives every pose)."""
        source = Path(source)
        if calibration is not None:
            raise InputError(f"colmap source {source}: the poses come from the sparse model; --calibration is not supported")
        scale = metres_per_unit(units)
        folder = model_folder(source)
        if folder is None:
            raise MissingFileError(f"colmap source {source}: no sparse model (sparse/0/cameras.bin and images.bin, or the .txt files)")
        binary = (folder / "cameras.bin").is_file() and (folder / "images.bin").is_file()
        cameras_file, images_file = (folder / f"{name}{'.bin' if binary else '.txt'}" for name in ("cameras", "images"))
        models = read_cameras_binary(cameras_file) if binary else read_cameras_text(cameras_file)
        registered = read_images_binary(images_file) if binary else read_images_text(images_file)
        if not registered:
            raise InputError(f"{images_file}: no registered images")
        for image in registered:
            if image.camera_id not in models:
                raise InputError(f"{images_file}: image {image.name!r} uses camera {image.camera_id}, which {cameras_file.name} lacks")
        missing = missing_files([source / "images" / image.name for image in registered], f"images listed in {images_file}", self.missing_frames)
        registered = [image for image in registered if source / "images" / image.name not in missing]
        if not registered:
            raise InputError(f"{images_file}: none of its images is on disk in {source / 'images'}")
        layout = self.layout
        if layout == "auto":
            layout = "video" if all(len(Path(image.name).parts) == 2 for image in registered) else "static"
        provenance = {
            "format": "colmap",
            "model": str(folder),
            "model_files": "binary" if binary else "text",
            "layout": layout,
            "principal_point": "cx, cy minus 0.5: COLMAP's pixel centres are at +0.5, mmcsplat's at integers",
        }
        if layout == "static":
            names = _static_names([image.name for image in registered])
            if len(set(names)) != len(names):
                repeated = sorted({name for name in names if names.count(name) > 1})
                raise InputError(f"{images_file}: images named alike give cameras {', '.join(map(repr, repeated))} twice; rename the images")
            cameras = [_camera(name, models[image.camera_id], image, scale, cameras_file, images_file) for name, image in zip(names, registered)]
            images = {name: {0: PosedImage(source / "images" / image.name, None, f"{images_file}: image {image.name!r}")}
                      for name, image in zip(names, registered)}
            return PosedImageRecording(source, cameras, images, np.zeros(1), stated_or_assumed(self.fps, 1, source), (), provenance)
        return self._open_video(source, models, registered, scale, cameras_file, images_file, provenance)

    def _open_video(self, source: Path, models: Mapping[int, ColmapCamera], registered: list[ColmapImage], scale: float,
                    cameras_file: Path, images_file: Path, provenance: dict[str, Any]) -> PosedImageRecording:
        """One camera per ``images/`` sub-folder, its frames matched by the numbers in their file names."""
        by_folder: dict[str, list[ColmapImage]] = {}
        for image in registered:
            parts = Path(image.name).parts
            if len(parts) != 2:
                raise InputError(f"{images_file}: image {image.name!r} is not in a camera folder (images/CAM/FILE); the video layout "
                                 "needs every image in one, or pass layout='static'")
            by_folder.setdefault(parts[0], []).append(image)
        cameras = []
        for name in sorted(by_folder):
            first, *others = by_folder[name]
            for other in others:
                if other.camera_id != first.camera_id or not (np.allclose(other.qvec, first.qvec, atol=1e-9) or
                                                              np.allclose(other.qvec, -np.array(first.qvec), atol=1e-9)) \
                        or not np.allclose(other.tvec, first.tvec, atol=1e-9):
                    raise InputError(f"{images_file}: images {first.name!r} and {other.name!r} of camera folder {name!r} differ in pose "
                                     "or camera; the video layout needs one fixed camera per folder (or pass layout='static')")
            cameras.append(_camera(name, models[first.camera_id], first, scale, cameras_file, images_file))
        unposed = sorted(folder.name for folder in (source / "images").iterdir()
                         if folder.is_dir() and folder.name not in by_folder and image_files(folder))
        if unposed:
            warnings.warn(f"{images_file}: no registered image in images/{', images/'.join(unposed)}; those folders are left out", stacklevel=3)
        files, num_frames, _ = frames_by_number({name: image_files(source / "images" / name) for name in sorted(by_folder)},
                                            self.missing_frames, source)
        images = {name: {t: PosedImage(path, None, f"{images_file}: camera folder {name!r}") for t, path in enumerate(paths) if path is not None}
                  for name, paths in files.items()}
        fps = stated_or_assumed(self.fps, num_frames, source)
        return PosedImageRecording(source, cameras, images, np.arange(num_frames) / fps, fps, (), provenance)


def _static_names(names: list[str]) -> list[str]:
    """A camera name per image: its file stem, or its path without suffix (``/`` as ``_``) when stems repeat."""
    stems = [Path(name).stem for name in names]
    if len(set(stems)) == len(stems):
        return stems
    return [str(Path(name).with_suffix("")).replace("/", "_") for name in names]


def rotation_from_quaternion(qvec: Any) -> np.ndarray:
    """The 3×3 rotation of a (w, x, y, z) quaternion (normalised first)."""
    w, x, y, z = np.asarray(qvec, dtype=np.float64) / np.linalg.norm(qvec)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _camera(name: str, model: ColmapCamera, image: ColmapImage, scale: float, cameras_file: Path, images_file: Path) -> Camera:
    """The mmcsplat camera of a registered image: K with the principal point moved to pixel-centre coordinates."""
    p = model.params
    where = f"{cameras_file}: camera {model.id}"
    if model.model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        distortion = [*p[3:], 0.0, 0.0, 0.0, 0.0][:4] if model.model != "SIMPLE_PINHOLE" else []
    else:
        fx, fy, cx, cy = p[:4]
        distortion = list(p[4:8]) if model.model in ("OPENCV", "OPENCV_FISHEYE") else []
    if not any(distortion):
        distortion = []
    if not (fx > 0 and fy > 0):
        raise InputError(f"{where} ({model.model}): focal lengths must be > 0, got {fx:g}, {fy:g}")
    K = np.array([[fx, 0.0, cx - PIXEL_CENTRE], [0.0, fy, cy - PIXEL_CENTRE], [0.0, 0.0, 1.0]])
    if not np.isfinite(np.linalg.norm(image.qvec)) or np.linalg.norm(image.qvec) < 1e-12:
        raise InputError(f"{images_file}: image {image.name!r}: qvec {list(image.qvec)} is not a rotation")
    try:
        return Camera(name=name, width=model.width, height=model.height, K=K, R=rotation_from_quaternion(image.qvec),
                      t=np.array(image.tvec) * scale, distortion=distortion, fisheye=model.model in FISHEYE_MODELS)
    except ValueError as error:
        raise InputError(f"{images_file}: image {image.name!r}: {error}") from error


def _model(where: str, model: str, width: int, height: int) -> None:
    """Refuse an unsupported model or an empty size."""
    if model not in MODEL_PARAMETERS:
        raise InputError(f"{where}: camera model {model} is not supported (only {', '.join(MODEL_PARAMETERS)}; undistort the "
                         "images with colmap image_undistorter first)")
    if width <= 0 or height <= 0:
        raise InputError(f"{where}: size {width}×{height} must be positive")


def _lines(path: Path) -> list[str]:
    """The lines of a text model file."""
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise MissingFileError(f"{path}: file not found") from None
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: not a text file: {error}") from error


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    """The cameras of a ``cameras.txt``, by id; errors name the file and line."""
    cameras = {}
    for number, line in enumerate(_lines(path), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        where = f"{path}: line {number}"
        fields = line.split()
        try:
            camera_id, model, width, height = int(fields[0]), fields[1], int(fields[2]), int(fields[3])
            params = tuple(float(value) for value in fields[4:])
        except (IndexError, ValueError):
            raise InputError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS…, got {line.strip()!r}") from None
        _model(f"{where}: camera {camera_id}", model, width, height)
        if len(params) != MODEL_PARAMETERS[model] or not np.all(np.isfinite(params)):
            raise InputError(f"{where}: camera {camera_id} ({model}) needs {MODEL_PARAMETERS[model]} finite parameters, got {len(params)}")
        if camera_id in cameras:
            raise InputError(f"{where}: camera id {camera_id} appears twice")
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def read_images_text(path: Path) -> list[ColmapImage]:
    """The registered images of an ``images.txt``; each image line is followed by its (ignored) points line."""
    lines = _lines(path)
    images = []
    number = 0
    while number < len(lines):
        line = lines[number]
        number += 1
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        where = f"{path}: line {number}"
        fields = line.split(maxsplit=9)
        try:
            image_id, camera_id = int(fields[0]), int(fields[8])
            qvec = tuple(float(value) for value in fields[1:5])
            tvec = tuple(float(value) for value in fields[5:8])
            name = fields[9].strip()
        except (IndexError, ValueError):
            raise InputError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {line.strip()!r}") from None
        if not np.all(np.isfinite(qvec + tvec)):
            raise InputError(f"{where}: image {name!r} has a pose that is not finite")
        images.append(ColmapImage(image_id, qvec, tvec, camera_id, name))  # type: ignore[arg-type]
        number += 1  # its 2D points line
    return _unique(path, images)


def _unique(path: Path, images: list[ColmapImage]) -> list[ColmapImage]:
    """Refuse repeated image ids or names."""
    for what, values in (("id", [image.id for image in images]), ("name", [image.name for image in images])):
        repeated = sorted({value for value in values if values.count(value) > 1}, key=str)
        if repeated:
            raise InputError(f"{path}: image {what}(s) {', '.join(map(repr, repeated))} appear more than once")
    return images


class _Bytes:
    """A cursor over a binary model file whose errors name the file and the offset."""

    def __init__(self, path: Path) -> None:
        try:
            self.data = path.read_bytes()
        except FileNotFoundError:
            raise MissingFileError(f"{path}: file not found") from None
        self.path = path
        self.offset = 0

    def read(self, format: str, what: str) -> tuple[Any, ...]:
        size = struct.calcsize(format)
        if self.offset + size > len(self.data):
            raise InputError(f"{self.path}: truncated at byte {self.offset} of {len(self.data)} (reading {what})")
        values = struct.unpack_from(format, self.data, self.offset)
        self.offset += size
        return values

    def skip(self, size: int, what: str) -> None:
        if self.offset + size > len(self.data):
            raise InputError(f"{self.path}: truncated at byte {self.offset} of {len(self.data)} (reading {what})")
        self.offset += size

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.offset)
        if end < 0:
            raise InputError(f"{self.path}: truncated at byte {self.offset} (reading {what}: no terminating NUL)")
        try:
            text = self.data[self.offset:end].decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{self.path}: byte {self.offset}: {what} is not UTF-8 text") from None
        self.offset = end + 1
        return text

    def finish(self) -> None:
        if self.offset != len(self.data):
            raise InputError(f"{self.path}: {len(self.data) - self.offset} unexpected bytes after the last entry (not a COLMAP binary model?)")


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    """The cameras of a ``cameras.bin``, by id; errors name the file, the camera and the byte offset."""
    cursor = _Bytes(path)
    (count,) = cursor.read("<Q", "the number of cameras")
    cameras = {}
    for index in range(count):
        camera_id, model_id, width, height = cursor.read("<iiQQ", f"camera {index}")
        model = MODEL_IDS.get(model_id, f"with id {model_id}")
        _model(f"{path}: camera {camera_id}", model, width, height)
        params = cursor.read(f"<{MODEL_PARAMETERS[model]}d", f"the parameters of camera {camera_id}")
        if not np.all(np.isfinite(params)):
            raise InputError(f"{path}: camera {camera_id} ({model}) has parameters that are not finite")
        if camera_id in cameras:
            raise InputError(f"{path}: camera id {camera_id} appears twice")
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    cursor.finish()
    return cameras


def read_images_binary(path: Path) -> list[ColmapImage]:
    """The registered images of an ``images.bin`` (2D points skipped); errors name the file and offset."""
    cursor = _Bytes(path)
    (count,) = cursor.read("<Q", "the number of images")
    images = []
    for index in range(count):
        image_id, *pose, camera_id = cursor.read("<i7di", f"image {index}")
        name = cursor.name(f"the name of image {image_id}")
        (points,) = cursor.read("<Q", f"the number of 2D points of image {name!r}")
        cursor.skip(24 * points, f"the 2D points of image {name!r}")
        if not np.all(np.isfinite(pose)):
            raise InputError(f"{path}: image {name!r} has a pose that is not finite")
        images.append(ColmapImage(image_id, tuple(pose[:4]), tuple(pose[4:]), camera_id, name))  # type: ignore[arg-type]
    cursor.finish()
    return _unique(path, images)
