"""The rig and one frame of a run as a nerfstudio dataset folder (``mmcsplat export RUN --transforms DIR``),
which nerfstudio's ``nerfstudio-data`` parser, gsplat's examples and other tools of that family read:

- ``DIR/images/CAMERA.png``: each camera's image of the run's fitted frame as the session holds it
  (undistorted at ingest);
- ``DIR/masks/CAMERA.png`` when the session has subject masks (255 subject, 0 elsewhere: nerfstudio
  trains only where a mask is non-zero, as a masked fit does);
- ``DIR/transforms.json``: ``camera_model`` ``OPENCV`` and one entry in ``frames`` per camera, each with
  its own intrinsics (``fl_x fl_y cx cy w h``, distortion ``k1 k2 p1 p2`` and ``k3`` when the camera has
  it), ``file_path``, ``mask_path`` and ``transform_matrix``; ``train_filenames`` / ``val_filenames``
  give the run's training and held-out cameras.

Conventions: ``transform_matrix`` is camera-to-world with OpenGL camera axes (x right, y up, looking along
−z), mmcsplat's OpenCV axes with y and z flipped; world units are metres. nerfstudio (like COLMAP) puts a
pixel's centre at (u + 0.5, v + 0.5) where mmcsplat puts it at (u, v), so ``cx``/``cy`` are mmcsplat's plus
0.5. The folder is written beside DIR under a temporary name and renamed into place.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import new_folder, write_json_atomic

#: OpenCV camera axes (y down, looking along +z) to OpenGL's (y up, looking along −z), and back.
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
#: Where mmcsplat's pixel centre (u, v) lies in nerfstudio's and COLMAP's pixel coordinates.
PIXEL_CENTRE = 0.5


def camera_to_world_gl(camera: Camera) -> np.ndarray:
    """The [4, 4] camera-to-world matrix of ``camera`` in OpenGL camera axes."""
    c2w = np.eye(4)
    c2w[:3, :3] = camera.R.T
    c2w[:3, 3] = camera.center
    return c2w @ CV_TO_GL


def intrinsics(camera: Camera) -> dict[str, Any]:
    """nerfstudio's per-frame intrinsics and OpenCV distortion of ``camera`` (a fisheye camera's with its own
    ``camera_model``)."""
    entry: dict[str, Any] = {"fl_x": float(camera.K[0, 0]), "fl_y": float(camera.K[1, 1]),
                             "cx": float(camera.K[0, 2]) + PIXEL_CENTRE, "cy": float(camera.K[1, 2]) + PIXEL_CENTRE,
                             "w": camera.width, "h": camera.height}
    if camera.fisheye:
        lens = camera.fisheye_coefficients.ravel()
        return {**entry, "camera_model": "OPENCV_FISHEYE", **{f"k{i + 1}": float(value) for i, value in enumerate(lens)}}
    distortion = [float(value) for value in camera.distortion] + [0.0] * (4 - len(camera.distortion))
    entry.update({"k1": distortion[0], "k2": distortion[1], "p1": distortion[2], "p2": distortion[3]})
    if len(distortion) > 4:
        entry["k3"] = distortion[4]
    return entry


def _write_image(path: Path, image: np.ndarray) -> None:
    """``image`` (BGR or grey) as a PNG at ``path``; an error naming it where OpenCV could not write it (a
    full disk), rather than a transforms.json that lists an image the folder lacks."""
    import cv2

    if not cv2.imwrite(str(path), image):
        raise OSError(f"{path}: OpenCV could not write it")


def export_transforms(run: str | Path, out: str | Path) -> Path:
    """Write the nerfstudio dataset folder of ``run``'s fitted frame to ``out`` (module docstring), which
    must not exist or be empty; returns the path of its transforms.json. Cameras without that frame are
    left out."""
    import cv2

    states = RunStates(run)
    session = states.session
    t = states.info.frame
    frames, names = [], []
    with new_folder(out) as folder:
        (folder / "images").mkdir()
        for name in session.camera_names:
            if not session.present(name)[t]:
                continue
            camera, data = session.camera(name), session.frame(t, name)
            image = f"images/{name}.png"
            _write_image(folder / image, cv2.cvtColor(np.ascontiguousarray(data.rgb), cv2.COLOR_RGB2BGR))
            entry = {"file_path": image, **intrinsics(camera), "transform_matrix": camera_to_world_gl(camera).tolist()}
            if data.mask is not None:
                (folder / "masks").mkdir(exist_ok=True)
                entry["mask_path"] = f"masks/{name}.png"
                _write_image(folder / entry["mask_path"], np.where(data.mask, 255, 0).astype(np.uint8))
            frames.append(entry)
            names.append(name)
        split = {role: [f"images/{name}.png" for name in cameras if name in names]
                 for role, cameras in (("train_filenames", states.info.train_cameras), ("val_filenames", states.info.heldout_cameras))}
        write_json_atomic(folder / "transforms.json", {"camera_model": "OPENCV", "frames": frames, **split})
    return Path(out) / "transforms.json"
