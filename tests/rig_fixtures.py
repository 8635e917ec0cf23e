"""Small real-rig captures made by the tests: a ring of distorted cameras, frames that encode their index,
and marker points drawn where the distorted cameras see them."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from mmcsplat.scene.camera import Camera, look_at
from mmcsplat.storage.calibration import write_calibration

#: Strong barrel distortion, so that skipping undistortion moves the markers by pixels.
DISTORTION = (-0.3, 0.1, 0.0, 0.0, 0.0)
#: A fisheye lens's (k1, k2, k3, k4), for ``ring_cameras(..., fisheye=True)``: pixels from where a pinhole would see.
FISHEYE = (-0.2, 0.02, 0.0, 0.0)
#: World points drawn as markers: a grid on the floor (z = 0) around the origin.
MARKERS = np.array([[x, y, 0.0] for x in (-0.8, -0.4, 0.0, 0.4, 0.8) for y in (-0.6, 0.0, 0.6)])


def ring_cameras(names: Sequence[str], width: int = 128, height: int = 96, distortion=None, fisheye: bool = False) -> list[Camera]:
    """Cameras on a ring of radius 1.5 m, 1.2 m up, looking at the origin, with ``distortion`` (by default
    :data:`DISTORTION`, or :data:`FISHEYE` for fisheye lenses)."""
    distortion = (FISHEYE if fisheye else DISTORTION) if distortion is None else distortion
    cameras = []
    for i, name in enumerate(names):
        angle = 2 * np.pi * i / len(names)
        centre = np.array([1.5 * np.cos(angle), 1.5 * np.sin(angle), 1.2])
        R = look_at(centre, np.zeros(3))
        K = [[0.8 * width, 0, (width - 1) / 2 + 1.5], [0, 0.8 * width, (height - 1) / 2 - 1.0], [0, 0, 1]]
        cameras.append(Camera(name, width, height, K, R, -R @ centre, distortion, fisheye=fisheye))
    return cameras


def background_level(t: int) -> int:
    """The grey level that identifies frame ``t`` (robust to lossy video compression)."""
    return 30 + (35 * t) % 200


def frame_image(camera: Camera, t: int) -> np.ndarray:
    """RGB frame ``t`` of ``camera``: a uniform grey encoding ``t`` and white discs at the markers' distorted
    projections (drawn with sub-pixel centres)."""
    image = np.full((camera.height, camera.width, 3), background_level(t), np.uint8)
    shift = 4
    for u, v in camera.project(MARKERS):
        centre = (round(u * (1 << shift)), round(v * (1 << shift)))
        cv2.circle(image, centre, 2 << shift, (255, 255, 255), -1, cv2.LINE_AA, shift)
    return image


def write_videos(folder: Path, cameras: Sequence[Camera], frames: int | Sequence[int], *, stems: Sequence[str] | None = None, fps: float = 30.0) -> None:
    """One mp4v video per camera (``stems`` names the files, the camera names by default)."""
    folder.mkdir(parents=True, exist_ok=True)
    counts = [frames] * len(cameras) if isinstance(frames, int) else list(frames)
    for camera, stem, count in zip(cameras, stems or [c.name for c in cameras], counts):
        writer = cv2.VideoWriter(str(folder / f"{stem}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), fps, (camera.width, camera.height))
        assert writer.isOpened()
        for t in range(count):
            writer.write(cv2.cvtColor(frame_image(camera, t), cv2.COLOR_RGB2BGR))
        writer.release()


def write_image_folders(folder: Path, cameras: Sequence[Camera], frames: int) -> None:
    """One folder of PNGs per camera, named ``frame{t}.png`` (so text order ≠ natural order past 9)."""
    for camera in cameras:
        (folder / camera.name).mkdir(parents=True, exist_ok=True)
        for t in range(frames):
            cv2.imwrite(str(folder / camera.name / f"frame{t}.png"), cv2.cvtColor(frame_image(camera, t), cv2.COLOR_RGB2BGR))


def make_capture(folder: Path, names: Sequence[str] = ("cam_a", "cam_b"), frames: int = 4, **camera_options) -> list[Camera]:
    """A ``videos`` capture: calibration.toml plus one video per camera; returns the calibrated cameras."""
    cameras = ring_cameras(names, **camera_options)
    folder.mkdir(parents=True, exist_ok=True)
    write_calibration(folder / "calibration.toml", cameras)
    write_videos(folder, cameras, frames)
    return cameras


def marker_offsets(image: np.ndarray, camera: Camera, radius: int = 3) -> np.ndarray:
    """[M] distances (px) between each visible marker's pinhole projection through ``camera`` and the
    brightness-weighted centroid of the disc drawn around it in ``image``."""
    grey = image.astype(np.float64).mean(axis=2)
    grey = np.clip(grey - np.median(grey), 0, None)
    offsets = []
    for u, v in camera.project(MARKERS):
        x0, y0 = round(u) - radius, round(v) - radius
        if x0 < 0 or y0 < 0 or x0 + 2 * radius >= camera.width or y0 + 2 * radius >= camera.height:
            continue
        window = grey[y0 : y0 + 2 * radius + 1, x0 : x0 + 2 * radius + 1]
        ys, xs = np.mgrid[y0 : y0 + 2 * radius + 1, x0 : x0 + 2 * radius + 1]
        total = window.sum()
        offsets.append(np.hypot((xs * window).sum() / total - u, (ys * window).sum() / total - v) if total > 0 else np.inf)
    return np.array(offsets)


def write_blank_session(url: Path, cameras: Sequence[Camera], frames: int) -> Path:
    """A session of black images at each camera's size, for tests that store their own flow beside them."""
    from mmcsplat.storage.session import SessionWriter

    with SessionWriter(url, cameras=cameras, num_frames=frames, fps=30.0) as writer:
        for camera in cameras:
            for t in range(frames):
                writer.write_frame(camera.name, t, np.zeros((camera.height, camera.width, 3), np.uint8))
    return url


def no_session_left(out: Path) -> bool:
    """Nothing at ``out`` and no partial or temporary sibling of it."""
    return not out.exists() and not any(p.name.startswith(f".{out.name}") for p in out.parent.iterdir())
