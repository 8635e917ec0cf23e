"""Read and write anipose ``calibration.toml`` files, and read Pose2Sim's variant of them, Caliscope's
``camera_array.toml``, EasyMocap's ``intri.yml`` + ``extri.yml`` (parsed by :mod:`.easymocap_calibration`),
Qualisys Track Manager's ``.qca.txt`` (parsed by :mod:`.qualisys_calibration`) and OpenCap's
``CamN/cameraIntrinsicsExtrinsics.pickle`` files (parsed by :mod:`.opencap_calibration`).

anipose (``CameraGroup.dump``) writes one ``[cam_N]`` table per camera with ``name``, ``size = [w, h]``,
``matrix`` (3×3 K), ``distortions`` (k1, k2, p1, p2, k3), ``rotation`` (a Rodrigues vector, world to
camera) and ``translation``, plus a ``[metadata]`` table; a fisheye camera (``FisheyeCamera``) adds
``fisheye = true`` and has 4 distortion values, OpenCV's fisheye (k1, k2, k3, k4). Pose2Sim names its tables
after the cameras, writes sizes as floats, 4 distortion values and ``fisheye = false``.

Caliscope's ``camera_array.toml`` holds the same keys in one ``[cameras.N]`` table per camera (N its
integer id), with the rotation a Rodrigues vector or, in files it wrote before, a 3×3 matrix, in metres;
its cameras are named ``cam_N``, as it names their videos (``cam_N.mp4``). Cameras marked ``ignore`` and
those it has not placed (no rotation or translation; files it wrote before write the string ``"null"`` for
a missing value) are left out, as Caliscope's own export to anipose leaves them out.

Translations in a file are in the calibration board's unit (``"m"`` or ``"mm"``; a Qualisys file's
and an OpenCap session's always millimetres), or ``"auto"``: whichever of the two puts the rig within :data:`RIG_RADIUS_M` — the two
readings differ a thousandfold, so at most one is a real rig. The cameras returned are always in metres. Tables named ``cam_N`` are ordered by N (``cam_10`` after ``cam_9``); a file whose
tables are named otherwise keeps the file's order.
"""

from __future__ import annotations

import logging
import re
import tomllib
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.rig import rig_center
from mmcsplat.storage.atomic import write_text_atomic
from mmcsplat.storage.easymocap_calibration import easymocap_files, easymocap_names, read_easymocap
from mmcsplat.storage.opencap_calibration import is_opencap, opencap_tables
from mmcsplat.storage.qualisys_calibration import is_qualisys, qualisys_tables

#: Metres per unit of a calibration file's translations.
UNITS = {"m": 1.0, "mm": 1e-3}
#: The units that let the rig decide (:func:`read_rig`); poses that carry no unit of their own take metres.
AUTO_UNITS = "auto"
#: What ``--units`` accepts.
UNIT_CHOICES = (AUTO_UNITS, *UNITS)

_ANIPOSE_SECTION = re.compile(r"cam_(\d+)")
_REQUIRED = ("size", "matrix", "distortions", "rotation", "translation")
#: The plausible extent of a rig, metres: its farthest camera from the cameras' centroid (a mouse arena's
#: cameras ~0.3 m, a motion-capture hall's ~10 m).
RIG_RADIUS_M = (0.05, 50.0)
#: How far outside its image (in image sizes) a camera may see the point the other cameras look at.
UNSEEN_MARGIN = 0.5
#: The least distance between two cameras' centres, metres: two camera bodies cannot stand closer.
MIN_CAMERA_GAP_M = 0.01
#: How much radial distortion may scale a radius within the image: beyond it the coefficients are wrong
#: (strong wide-angle lenses scale their corners by 0.6–0.8; a fisheye's scale from θ to tan θ is its model's).
RADIAL_SCALE = (1 / 3, 3.0)

logger = logging.getLogger(__name__)


def metres_per_unit(units: str) -> float:
    """The scale from ``units`` ("m", "mm", or "auto": metres, for poses that carry no unit of their own) to
    metres; a clear error for anything else."""
    if units == AUTO_UNITS:
        return UNITS["m"]
    try:
        return UNITS[units]
    except KeyError:
        raise InputError(f"unknown calibration units {units!r}; choose one of {', '.join(UNIT_CHOICES)}") from None


@attrs.frozen
class Rig:
    """A calibration's ``cameras`` (metres) and the ``units`` its translations were read in ("m" or "mm")."""

    cameras: list[Camera]
    units: str


def read_rig(path: Path, units: str = AUTO_UNITS, cameras: Sequence[str] | None = None,
             sizes: Mapping[str, tuple[int, int]] | None = None) -> Rig:
    """The cameras of an anipose or Pose2Sim ``calibration.toml``, of Caliscope's ``camera_array.toml``, of EasyMocap's ``intri.yml`` and
    ``extri.yml`` (``path`` either of them or their folder: :mod:`.easymocap_calibration`), of Qualisys's ``.qca.txt``, or of
    OpenCap's session (``path`` one camera's ``cameraIntrinsicsExtrinsics.pickle``: :mod:`.opencap_calibration`), in metres,
    and the units they were read in.

    ``units`` is the unit of the file's translations, or ``"auto"``: the one that puts the rig within
    :data:`RIG_RADIUS_M` (module docstring); a Qualisys file's and OpenCap's are millimetres whatever it says. ``cameras`` (names) keeps only those, in the file's
    order, and checks only them: a broken camera left out (a copied table) does not stop the others.
    ``sizes`` (name → width, height) gives the image size of a camera whose file states none (EasyMocap's
    may not): the readers pass their decoded frames' sizes; a stated size wins. Errors name the file and
    the table or camera at fault.
    """
    path = Path(path)
    metres_per_unit(units)  # unknown units are refused before the file is read
    units = format_units(path) or units
    pair = easymocap_files(path)
    if pair:
        where = f"calibration {pair[0]} and {pair[1].name}"
        read = read_easymocap(*pair, calibration_names(path, cameras), sizes)
    else:
        where = f"calibration {path}"
        tables = _tables(path)
        names = _select(path, [name for name, _, _ in tables], cameras)
        read = [_camera(path, name, section, table) for name, section, table in tables if name in names]
    if units == AUTO_UNITS:
        units = _rig_units(read, where)
    read = [camera.with_units(UNITS[units]) for camera in read]
    check_rig(read, where, units)
    return Rig(read, units)


def format_units(path: Path) -> str | None:
    """The unit a calibration's format always writes translations in (Qualisys's and OpenCap's millimetres),
    or None where the file's unit varies with the board."""
    return "mm" if is_qualisys(path) or is_opencap(path) else None


def read_calibration(path: Path, units: str = AUTO_UNITS, cameras: Sequence[str] | None = None,
                     sizes: Mapping[str, tuple[int, int]] | None = None) -> list[Camera]:
    """The cameras of :func:`read_rig`, in metres."""
    return read_rig(path, units, cameras, sizes).cameras


def _rig_radius(cameras: Sequence[Camera]) -> float:
    """The farthest camera's distance from the cameras' centroid, in their units."""
    centres = np.array([camera.center for camera in cameras])
    return float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).max())


def _rig_units(cameras: Sequence[Camera], where: str) -> str:
    """The units in which ``cameras`` (read unscaled) form a plausible rig: metres unless only millimetres
    do (one camera, which has no extent, is read in metres); an error when neither does."""
    if len(cameras) < 2:
        return "m"
    radius = _rig_radius(cameras)
    low, high = RIG_RADIUS_M
    for units, scale in UNITS.items():
        if low <= radius * scale <= high:
            if units != "m":
                logger.info("%s: translations read in %s: its cameras lie up to %.4g m from their centre so, %.4g m in metres",
                            where, units, radius * scale, radius)
            return units
    raise InputError(f"{where}: the cameras lie up to {radius:.4g} units from their centre, outside the {low:g}–{high:g} m of any real "
                     "rig whether the units are metres or millimetres: check the translations")


def calibration_names(path: Path, cameras: Sequence[str] | None = None) -> list[str]:
    """The names of the calibration's cameras (only ``cameras``, an error naming any it lacks), in its
    order, without reading the cameras: what the readers match files to before the files' images give the
    sizes :func:`read_calibration` may need."""
    path = Path(path)
    pair = easymocap_files(path)
    return _select(path, easymocap_names(pair[0]) if pair else [name for name, _, _ in _tables(path)], cameras)


def is_camera_toml(path: Path) -> bool:
    """Whether a ``.toml`` file may be a calibration: not one that parses and holds no camera table (a
    Pose2Sim project's ``Config.toml`` beside its videos). A file that does not parse counts, so that
    reading it says what is wrong."""
    try:
        with Path(path).open("rb") as file:
            document = tomllib.load(file)
    except (OSError, tomllib.TOMLDecodeError):
        return True
    tables = [value for key, value in document.items() if key != "metadata" and isinstance(value, dict)]
    cameras = document.get("cameras")
    if isinstance(cameras, dict):
        tables += [value for value in cameras.values() if isinstance(value, dict)]
    return any("matrix" in table for table in tables)


def _tables(path: Path) -> list[tuple[str, str, dict[str, Any]]]:
    """A calibration's camera tables as (name, where in the file, table): a Qualisys file's in its order, a
    TOML file's ``cam_N`` by N, others in the file's order."""
    if is_qualisys(path):
        return qualisys_tables(path)
    if is_opencap(path):
        return opencap_tables(path)
    try:
        with path.open("rb") as file:
            document = tomllib.load(file)
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"calibration {path}: not valid TOML: {error}") from error
    caliscope = document.get("cameras")
    if isinstance(caliscope, dict) and caliscope and all(isinstance(value, dict) for value in caliscope.values()):
        return _caliscope_tables(path, caliscope)
    sections = []
    for key, value in document.items():
        if key == "metadata":
            continue
        if not isinstance(value, dict):
            raise InputError(f"calibration {path}: unexpected top-level key {key!r} (cameras are tables like [cam_0])")
        sections.append(key)
    if not sections:
        raise InputError(f"calibration {path}: no camera tables (expected [cam_0], [cam_1], …)")
    numbers = [_ANIPOSE_SECTION.fullmatch(key) for key in sections]
    if all(numbers):
        sections = [key for _, key in sorted(zip((int(m.group(1)) for m in numbers), sections))]
    tables = [(document[key].get("name", key), f"[{key}]", document[key]) for key in sections]
    for name, section, _ in tables:
        if not isinstance(name, str):
            raise InputError(f"calibration {path}, {section}: name must be a string, got {name!r}")
    return tables


def _caliscope_tables(path: Path, cameras: dict[str, dict[str, Any]]) -> list[tuple[str, str, dict[str, Any]]]:
    """Caliscope's placed, not ignored ``[cameras.N]`` tables as (``cam_N``, section, table), by N."""
    tables = []
    for key, table in cameras.items():
        if not key.isdigit():
            raise InputError(f"calibration {path}, [cameras.{key}]: Caliscope's camera tables are numbered ([cameras.0], [cameras.1], …)")
        table = {name: value for name, value in table.items() if value != "null"}
        if table.get("ignore") is not True and "rotation" in table and "translation" in table:
            tables.append((int(key), (f"cam_{key}", f"[cameras.{key}]", table)))
    if not tables:
        raise InputError(f"calibration {path}: Caliscope has placed none of its cameras (none has a rotation and translation "
                         "that is not ignored): calibrate the extrinsics first")
    return [entry for _, entry in sorted(tables)]


def _select(path: Path, names: list[str], cameras: Sequence[str] | None) -> list[str]:
    """``names`` that are in ``cameras`` (all when None), in the file's order; an error naming any camera the
    file lacks, or any chosen name it gives twice."""
    if cameras is not None:
        unknown = [name for name in cameras if name not in names]
        if unknown:
            raise InputError(f"calibration {path}: no camera named {', '.join(map(repr, unknown))}; cameras are {', '.join(names)}")
        names = [name for name in names if name in cameras]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise InputError(f"calibration {path}: camera names {duplicates} appear more than once")
    return names


def check_distortion(camera: Camera, where: str) -> None:
    """Refuse radial distortion no lens has: over the image's radius (the principal point to its farthest
    corner, in normalised coordinates) the mapping r → r (1 + k1 r² + k2 r⁴ + k3 r⁶) must rise (else the
    image folds over itself) and stay within :data:`RADIAL_SCALE` of r (else pixels move off the image).
    A fisheye's θ → θ (1 + k1 θ² + … + k4 θ⁸) must rise up to the image's radius (:func:`_check_fisheye`)."""
    if camera.fisheye:
        _check_fisheye(camera, where)
        return
    if not camera.is_distorted:
        return
    k1, k2, _, _, k3 = np.pad(camera.distortion, (0, 5 - len(camera.distortion)))
    reach = _image_reach(camera)
    r2 = np.linspace(0.0, reach, 257)[1:] ** 2
    scale = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3  # distorted radius / undistorted radius
    slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3  # d(distorted radius) / d(radius)
    coefficients = ", ".join(f"{name} = {value:g}" for name, value in zip(("k1", "k2", "p1", "p2", "k3"), camera.distortion, strict=False))
    low, high = RADIAL_SCALE
    if np.any(slope <= 0):
        at = float(np.sqrt(r2[np.argmax(slope <= 0)]) / reach)
        raise InputError(f"{where}: camera {camera.name!r}: its distortion ({coefficients}) folds the image over itself at {at:.0%} of "
                         "the way to its corner (no lens does); check the coefficients and their order (k1 k2 p1 p2 k3)")
    if np.any((scale < low) | (scale > high)):
        raise InputError(f"{where}: camera {camera.name!r}: its distortion ({coefficients}) moves the image's corner {scale[-1]:.3g} times "
                         f"as far from the centre (plausible lenses stay within {low:g}–{high:g}); check the coefficients and their order")


def _image_reach(camera: Camera) -> float:
    """The image's radius in normalised coordinates: from the principal point to the farthest corner."""
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
    corners = np.array([[0, 0], [camera.width, 0], [0, camera.height], [camera.width, camera.height]], dtype=np.float64)
    return float(np.max(np.hypot((corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy)))


def _check_fisheye(camera: Camera, where: str) -> None:
    """Refuse fisheye coefficients under which the image folds over itself: θ_d(θ) = θ (1 + k1 θ² + k2 θ⁴ +
    k3 θ⁶ + k4 θ⁸) must rise from the optical axis until it reaches the image's corner (or θ = π/2, beyond
    which OpenCV's model sees nothing)."""
    k = camera.fisheye_coefficients.ravel()
    theta = np.linspace(0.0, np.pi / 2, 513)[1:]
    reached = theta * (1 + k[0] * theta**2 + k[1] * theta**4 + k[2] * theta**6 + k[3] * theta**8)
    slope = 1 + 3 * k[0] * theta**2 + 5 * k[1] * theta**4 + 7 * k[2] * theta**6 + 9 * k[3] * theta**8
    inside = np.cumsum(reached >= _image_reach(camera)) <= 1  # up to and including the first angle at the corner
    folds = (slope <= 0) & inside
    if np.any(folds):
        coefficients = ", ".join(f"{name} = {value:g}" for name, value in zip(("k1", "k2", "k3", "k4"), k, strict=True))
        raise InputError(f"{where}: camera {camera.name!r}: its fisheye distortion ({coefficients}) folds the image over itself "
                         f"{np.degrees(theta[np.argmax(folds)]):.0f}° from the optical axis, inside the image (no lens does); check the "
                         "coefficients and their order (k1 k2 k3 k4)")


def check_rig(cameras: Sequence[Camera], where: str, units: str) -> None:
    """Refuse a rig no real capture has: a focal length ≤ 0, a principal point far outside its image,
    implausible distortion (:func:`check_distortion`), two
    cameras with the same pose (a copy-paste error), two closer than :data:`MIN_CAMERA_GAP_M` (one camera's
    translation in another unit), or a rig whose extent (the farthest camera from the
    cameras' centroid) is outside :data:`RIG_RADIUS_M` — then the units are most likely wrong."""
    for camera in cameras:
        fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
        if not (fx > 0 and fy > 0):
            raise InputError(f"{where}: camera {camera.name!r} has focal lengths {fx:g}, {fy:g} pixels; both must be > 0")
        if not (-0.5 * camera.width <= cx <= 1.5 * camera.width and -0.5 * camera.height <= cy <= 1.5 * camera.height):
            raise InputError(f"{where}: camera {camera.name!r} has its principal point ({cx:g}, {cy:g}) far outside its "
                             f"{camera.width}×{camera.height} image (is the size or the matrix wrong?)")
        check_distortion(camera, where)
    for index, first in enumerate(cameras):
        for second in cameras[index + 1:]:
            if np.allclose(first.R, second.R, atol=1e-9) and np.allclose(first.t, second.t, atol=1e-9):
                raise InputError(f"{where}: cameras {first.name!r} and {second.name!r} have the same pose (a copied table?): leave the copy "
                                 "out with --cameras (mmcsplat ingest and run), or delete its table from the file")
    if len(cameras) < 2:
        return
    radius = _rig_radius(cameras)
    low, high = RIG_RADIUS_M
    if not low <= radius <= high:
        other = {"m": "mm", "mm": "m"}.get(units)
        hint = f"; if the file is in {other}, pass --units {other}" if other else ""
        raise InputError(f"{where}: the cameras lie up to {radius:.4g} m from their centre read in {units}, outside the {low:g}–{high:g} m "
                         f"of any real rig{hint}")
    _warn_unseen_centre(cameras, where)
    centres = np.array([camera.center for camera in cameras])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.diag(np.full(len(cameras), np.inf))
    first, second = np.unravel_index(np.argmin(gaps), gaps.shape)
    if gaps[first, second] < MIN_CAMERA_GAP_M:
        raise InputError(f"{where}: cameras {cameras[first].name!r} and {cameras[second].name!r} stand {gaps[first, second] * 1000:.3g} mm apart "
                         f"read in {units}, closer than any two cameras of a rig: is one camera's translation in another unit?")


def _warn_unseen_centre(cameras: Sequence[Camera], where: str) -> None:
    """Warn about a camera that does not see the point the others look at (:func:`~mmcsplat.scene.rig.rig_center`
    of the others, where their axes are not parallel): it lies behind it, or projects more than half an image
    outside its image. A pose written camera-to-world (the inverse of the world-to-camera one the formats hold)
    turns a camera so: on the Pose2Sim demo's rig each camera so inverted sees it 0.9–1.6 images off its edge,
    where every camera of ../shared/data's six real rigs sees it inside its image."""
    if len(cameras) < 3:
        return
    for camera in cameras:
        try:
            centre = rig_center([other for other in cameras if other is not camera])
        except InputError:  # the others' axes are parallel: no point they all look at
            continue
        seen = camera.R @ centre + camera.t
        pixel = (camera.K @ (seen / seen[2]))[:2] if seen[2] > 0 else None
        size = np.array([camera.width, camera.height])
        if pixel is None or np.any(pixel < -UNSEEN_MARGIN * size) or np.any(pixel > (1 + UNSEEN_MARGIN) * size):
            at = "lies behind it" if pixel is None else f"projects to ({pixel[0]:.0f}, {pixel[1]:.0f}), outside its {camera.width}×{camera.height} image"
            warnings.warn(f"{where}: camera {camera.name!r} does not see the point the other cameras look at (it {at}): is its pose the "
                          "inverse (camera-to-world) of the world-to-camera one the file should hold?", stacklevel=4)


def _camera(path: Path, name: str, section: str, table: dict[str, Any]) -> Camera:
    """Camera ``name`` from its table (``section``: where it is in the file), in the file's units."""
    where = f"calibration {path}, {section}"
    missing = [key for key in _REQUIRED if key not in table]
    if missing:
        raise InputError(f"{where}: missing {', '.join(missing)}")
    fisheye = table.get("fisheye", False)
    if not isinstance(fisheye, bool):
        raise InputError(f"{where}: fisheye must be true or false, got {fisheye!r}")
    size = _array(where, "size", table["size"], (2,))
    if np.any(size != np.round(size)) or np.any(size <= 0):
        raise InputError(f"{where}: size must be two positive whole numbers [width, height], got {table['size']}")
    distortion = _array(where, "distortions", table["distortions"], None).reshape(-1)
    if fisheye and distortion.size != 4:
        raise InputError(f"{where}: a fisheye camera's distortions must hold 4 values (k1 k2 k3 k4), got {distortion.size}")
    if distortion.size not in (4, 5):
        raise InputError(f"{where}: distortions must hold 4 (k1 k2 p1 p2) or 5 (… k3) values, got {distortion.size}")
    K = _array(where, "matrix", table["matrix"], (3, 3))
    R = _array(where, "rotation", table["rotation"], None)
    if R.shape not in ((3,), (3, 3)):
        raise InputError(f"{where}: rotation must be a Rodrigues vector [3] or a matrix [3, 3], got shape {list(R.shape)}")
    t = _array(where, "translation", table["translation"], (3,))
    try:  # the Camera's own checks name the camera, not the file: add it (once)
        return Camera(name=name, width=int(size[0]), height=int(size[1]), K=K, R=R, t=t, distortion=distortion, fisheye=fisheye)
    except ValueError as error:
        raise InputError(f"{where}: {error}") from error


def _array(where: str, key: str, value: Any, shape: tuple[int, ...] | None) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (any shape when None), or an error naming ``key``."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} must be numbers, got {value!r}") from None
    if shape is not None and array.shape != shape:
        raise InputError(f"{where}: {key} must have shape {list(shape)}, got {list(array.shape)}")
    if not np.all(np.isfinite(array)):
        raise InputError(f"{where}: {key} is not finite: {value!r}")
    return array


def write_calibration(path: Path, cameras: Sequence[Camera], units: str = "m", metadata: dict | None = None) -> None:
    """Write ``cameras`` (metres) as an anipose ``calibration.toml`` with translations in ``units``.

    Tables are ``[cam_0]``, ``[cam_1]``, … in the given order, each with 5 distortion values (zeros
    padded), or a fisheye camera's 4 and ``fisheye = true`` as aniposelib writes them; ``metadata`` becomes
    the ``[metadata]`` table. The file is replaced atomically.
    """
    import tomli_w

    path = Path(path)
    scale = metres_per_unit(units)
    document: dict[str, Any] = {}
    for index, camera in enumerate(cameras):
        distortion = np.zeros(4 if camera.fisheye else 5)
        distortion[: camera.distortion.size] = camera.distortion
        document[f"cam_{index}"] = {
            "name": camera.name,
            "size": [camera.width, camera.height],
            "matrix": camera.K.tolist(),
            "distortions": distortion.tolist(),
            "rotation": camera.rvec.tolist(),
            "translation": (camera.t / scale).tolist(),
            **({"fisheye": True} if camera.fisheye else {}),
        }
    document["metadata"] = dict(metadata or {})
    write_text_atomic(path, tomli_w.dumps(document))
