"""Calibrated cameras, in metres and OpenCV axes: a pinhole with OpenCV's lens distortion, or OpenCV's fisheye
(Kannala–Brandt) model. The distortion is applied and undone by OpenCV (``cv2`` and ``cv2.fisheye``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError


def _float_array(shape: tuple[int, ...]):
    """An attrs converter to a float64 array, and a validator of its shape."""

    def convert(value: Any) -> np.ndarray:
        array = np.array(value, dtype=np.float64)
        array.setflags(write=False)
        return array

    def validate(instance: Any, attribute: attrs.Attribute, value: np.ndarray) -> None:
        if value.shape != shape:
            raise InputError(f"camera {getattr(instance, 'name', '?')!r}: {attribute.name} must have shape {shape}, got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise InputError(f"camera {getattr(instance, 'name', '?')!r}: {attribute.name} is not finite")

    return {"converter": convert, "validator": validate}


def resize_matrix(sx: float, sy: float) -> np.ndarray:
    """[3, 3] S with S @ K the intrinsics of an image resized by (sx, sy). Pixel (u, v) is centred at the
    continuous point (u, v), so the image's edge lies at −0.5: coordinates map as x' = sx·(x + 0.5) − 0.5."""
    return np.array([[sx, 0.0, 0.5 * (sx - 1)], [0.0, sy, 0.5 * (sy - 1)], [0.0, 0.0, 1.0]])


def look_at(
    centre: Sequence[float], target: Sequence[float], roll: float = 0.0, up: Sequence[float] = (0.0, 0.0, 1.0), dtype: type = np.float64
) -> np.ndarray:
    """The [3, 3] world-to-camera rotation (OpenCV axes: x right, y down, z forward) of a camera at
    ``centre`` looking at ``target``: z = normalize(target − centre), x = normalize(z × up), y = z × x,
    then turned by ``roll`` radians about the optical axis; computed in ``dtype``."""
    centre, target = np.asarray(centre, dtype=dtype), np.asarray(target, dtype=dtype)
    forward = (target - centre) / np.linalg.norm(target - centre)
    right = np.cross(forward, np.asarray(up, dtype=dtype))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c, s = np.cos(roll), np.sin(roll)
    return np.stack([c * right + s * down, -s * right + c * down, forward]).astype(dtype)


def _distortion(value: Any) -> np.ndarray:
    array = np.array(value if value is not None else [], dtype=np.float64).reshape(-1)
    array.setflags(write=False)
    return array


def _check_distortion(instance: Camera, attribute: attrs.Attribute, value: np.ndarray) -> None:
    if not np.all(np.isfinite(value)):
        raise InputError(f"camera {instance.name!r}: distortion must be finite, got {value.tolist()}")
    if instance.fisheye and value.size not in (0, 4):
        raise InputError(f"camera {instance.name!r}: a fisheye camera's distortion must be 0 or 4 values (k1 k2 k3 k4), got {value.tolist()}")
    if not instance.fisheye and value.size not in (0, 4, 5):
        raise InputError(f"camera {instance.name!r}: distortion must be 0, 4 (k1 k2 p1 p2) or 5 (… k3) values, got {value.tolist()}")


#: How far R·Rᵀ may be from the identity: a matrix written to 4 decimals is within 1e-4 of it.
ORTHONORMAL_TOLERANCE = 1e-3
#: Undoing a distortion iterates; OpenCV's default stops after 5 steps, short of a strong lens's exact inverse.
_UNDISTORT_CRITERIA = (3, 100, 1e-12)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, steps, tolerance


def _rotation_matrix(value: Any) -> np.ndarray:
    """Accepts a 3×3 matrix or a Rodrigues vector."""
    array = np.array(value, dtype=np.float64)
    if array.shape in ((3,), (3, 1), (1, 3)):
        import cv2

        array, _ = cv2.Rodrigues(array.reshape(3, 1))
    array.setflags(write=False)
    return array


@attrs.frozen(eq=False)
class Camera:
    """One calibrated camera.

    ``K`` is the 3×3 intrinsic matrix in pixels; ``distortion`` holds OpenCV's (k1, k2, p1, p2[, k3]) or is
    empty for an ideal pinhole; ``R`` (3×3) and ``t`` (3,) map world points to camera coordinates,
    ``x_cam = R @ x_world + t``, with OpenCV axes (x right, y down, z forward) and metres throughout.
    ``fisheye`` selects OpenCV's fisheye model instead (``cv2.fisheye``): a ray at angle θ to the optical
    axis lands at θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸) from the principal point in normalised
    coordinates, ``distortion`` holding (k1, k2, k3, k4); without coefficients that is the equidistant
    projection, still not a pinhole.
    """

    name: str = attrs.field(validator=attrs.validators.instance_of(str))
    width: int = attrs.field(converter=int)
    height: int = attrs.field(converter=int)
    K: np.ndarray = attrs.field(**_float_array((3, 3)))
    R: np.ndarray = attrs.field(converter=_rotation_matrix, validator=_float_array((3, 3))["validator"])
    t: np.ndarray = attrs.field(**_float_array((3,)))
    distortion: np.ndarray = attrs.field(factory=lambda: np.zeros(0), converter=_distortion, validator=_check_distortion)
    fisheye: bool = attrs.field(default=False, converter=bool, kw_only=True)

    def __attrs_post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"camera {self.name!r}: image size must be positive, got {self.width}×{self.height}")
        if abs(np.linalg.det(self.R) - 1.0) > 1e-4:
            raise InputError(f"camera {self.name!r}: R is not a rotation (det {np.linalg.det(self.R):.6f})")
        # A determinant of 1 lets a shear or a stretch through, which moves the camera's centre and bends its rays.
        if (off := float(np.abs(self.R @ self.R.T - np.eye(3)).max())) > ORTHONORMAL_TOLERANCE:
            raise InputError(f"camera {self.name!r}: R is not a rotation (its rows are {off:.3g} from orthonormal)")
        if not np.allclose(self.K[2], (0.0, 0.0, 1.0), atol=1e-9) or self.K[1, 0] != 0.0:
            transposed = np.allclose(self.K.T[2], (0.0, 0.0, 1.0), atol=1e-9) and self.K.T[1, 0] == 0.0
            raise InputError(f"camera {self.name!r}: K {np.round(self.K, 3).tolist()} is not an intrinsic matrix [[fx, skew, cx], [0, fy, cy], "
                             "[0, 0, 1]]" + (": it is one transposed (MATLAB's layout)" if transposed else ""))

    @property
    def rvec(self) -> np.ndarray:
        """The rotation as a Rodrigues vector (3,)."""
        import cv2

        return cv2.Rodrigues(np.ascontiguousarray(self.R))[0].reshape(3)

    @property
    def center(self) -> np.ndarray:
        """The camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def world_to_camera(self) -> np.ndarray:
        """The 4×4 world-to-camera matrix."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.R
        matrix[:3, 3] = self.t
        return matrix

    @property
    def is_distorted(self) -> bool:
        """Whether the camera is anything but an ideal pinhole (a fisheye always is)."""
        return self.fisheye or bool(np.any(self.distortion != 0))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points [N, 3] to pixels [N, 2], applying the lens model."""
        import cv2

        points = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
        if len(points) == 0:
            return np.zeros((0, 2))
        if self.fisheye:
            pixels, _ = cv2.fisheye.projectPoints(points, self.rvec.reshape(3, 1), self.t.reshape(3, 1), self.K, self.fisheye_coefficients)
        else:
            pixels, _ = cv2.projectPoints(points, self.rvec, self.t, self.K, self.distortion if self.distortion.size else None)
        return pixels.reshape(-1, 2)

    def distort(self, normalized: np.ndarray) -> np.ndarray:
        """Pixels [N, 2] of normalised image coordinates [N, 2] (x/z, y/z in the camera's frame)."""
        import cv2

        normalized = np.asarray(normalized, dtype=np.float64).reshape(-1, 2)
        if len(normalized) == 0:
            return np.zeros((0, 2))
        if self.fisheye:
            return cv2.fisheye.distortPoints(normalized.reshape(-1, 1, 2), self.K, self.fisheye_coefficients).reshape(-1, 2)
        rays = np.concatenate([normalized, np.ones((len(normalized), 1))], axis=1)
        pixels, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), self.K, self.distortion if self.distortion.size else None)
        return pixels.reshape(-1, 2)

    def undistort(self, pixels: np.ndarray, new_K: np.ndarray | None = None) -> np.ndarray:
        """The inverse of the lens model: [..., 2] pixels → normalised image coordinates, or the pixels of
        an ideal pinhole with intrinsics ``new_K`` when given."""
        import cv2

        pixels = np.asarray(pixels, dtype=np.float64)
        flat = np.ascontiguousarray(pixels.reshape(-1, 1, 2))
        if len(flat) == 0:
            return pixels.copy()
        P = None if new_K is None else np.asarray(new_K, dtype=np.float64)
        if self.fisheye:
            mapped = cv2.fisheye.undistortPoints(flat, self.K, self.fisheye_coefficients, R=np.eye(3), P=P, criteria=_UNDISTORT_CRITERIA)
        else:
            mapped = cv2.undistortPoints(flat, self.K, self.distortion if self.distortion.size else None, P=P, criteria=_UNDISTORT_CRITERIA)
        return mapped.reshape(pixels.shape)

    @property
    def fisheye_coefficients(self) -> np.ndarray:
        """A fisheye camera's (k1, k2, k3, k4), zeros where none are given, as ``cv2.fisheye`` takes them."""
        return np.pad(self.distortion, (0, 4 - self.distortion.size)).reshape(4, 1)

    def scaled(self, sx: float, sy: float | None = None) -> Camera:
        """This camera for an image resized by (sx, sy): K scaled so pixel centres stay consistent."""
        sy = sx if sy is None else sy
        return attrs.evolve(self, K=resize_matrix(sx, sy) @ self.K, width=round(self.width * sx), height=round(self.height * sy))

    def with_units(self, metres_per_unit: float) -> Camera:
        """This camera with its translation rescaled to metres."""
        return attrs.evolve(self, t=self.t * metres_per_unit)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable description (the session store keeps cameras this way)."""
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "distortion": self.distortion.tolist(),
            **({"fisheye": True} if self.fisheye else {}),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Camera:
        """The inverse of :meth:`to_dict` (``fisheye`` is written only when true)."""
        return cls(**{key: data[key] for key in ("name", "width", "height", "K", "R", "t", "distortion")}, fisheye=data.get("fisheye", False))
