"""The synthetic infant seen by one moving camera: a monocular capture in the D-NeRF layout.

One pinhole camera circles the mat (``turns`` times over the sequence, at the ring's radius and height,
looking at the mat's centre) and takes one image per frame; these are ``transforms_train.json``. A ring of
``config.cameras`` fixed held-out cameras, set half-way between the ring positions of the multi-view
capture, images every ``heldout_every``-th frame; these are ``transforms_test.json``, which the ``dnerf``
reader holds out. Images are RGBA PNGs whose alpha is the infant's mask (the mat and its texture are in the
colour channels; the reader composites them over black, as D-NeRF's Blender renders come). Times are
written in seconds, which the reader reads back as such, so speeds keep their units.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.scene.camera import Camera, look_at
from mmcsplat.storage.atomic import new_folder
from mmcsplat.synthetic.body import BodyPose
from mmcsplat.synthetic.cameras import REFERENCE_FOCAL, REFERENCE_WIDTH, RING_HEIGHT, RING_RADIUS
from mmcsplat.synthetic.scene import ViewRenderer
from mmcsplat.synthetic.synthesize import SynthConfig, infant_motion

#: OpenCV camera axes to OpenGL's (y up, looking along −z), as D-NeRF's transform matrices use them.
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
TARGET = (0.0, 0.0, 0.05)  # where every camera looks: the mat's centre, a little above it


@attrs.frozen
class MonocularResult:
    """What :func:`synthesize_monocular` wrote: the capture folder, its training (orbit) and held-out
    images, and the seconds it took."""

    out_dir: Path
    train_images: int
    heldout_images: int
    seconds: float


def circle_camera(name: str, azimuth: float, width: int, height: int) -> Camera:
    """An undistorted camera on the synthetic rig's circle at ``azimuth`` radians, looking at the mat,
    with the reference rig's focal length scaled to ``width`` and the principal point at the image centre
    (as a Blender render has it)."""
    centre = np.array([RING_RADIUS * np.cos(azimuth), RING_RADIUS * np.sin(azimuth), RING_HEIGHT])
    R = look_at(centre, TARGET)
    focal = REFERENCE_FOCAL * width / REFERENCE_WIDTH
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return Camera(name, width, height, K, R, -R @ centre, [0.0] * 5)


def transform_matrix(camera: Camera) -> list[list[float]]:
    """``camera``'s camera-to-world matrix in OpenGL axes, D-NeRF's ``transform_matrix``."""
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = camera.R.T, camera.center
    return (c2w @ CV_TO_GL).tolist()


def synthesize_monocular(out_dir: str | Path, config: SynthConfig = SynthConfig(), *, turns: float = 1.0, heldout_every: int = 5,
                         progress: bool = True) -> MonocularResult:
    """Render the infant of ``config`` (its seed, frames, frame rate, size and slide; no adult's leg) seen by
    one camera orbiting ``turns`` times and by ``config.cameras`` fixed held-out cameras every
    ``heldout_every``-th frame, into ``out_dir`` in the D-NeRF layout (module docstring). The folder appears
    only once complete."""
    import cv2
    from tqdm import tqdm

    started = time.perf_counter()
    parts, times, poses = infant_motion(config)
    orbit = [circle_camera(f"orbit_{t:03d}", 2 * np.pi * turns * t / config.frames, config.width, config.height) for t in range(config.frames)]
    fixed = [circle_camera(f"fixed_{i}", 2 * np.pi * (i + 0.5) / config.cameras, config.width, config.height) for i in range(config.cameras)]
    fixed_views = [ViewRenderer(camera, config.samples, None) for camera in fixed]
    angle = 2 * np.arctan(0.5 * config.width / orbit[0].K[0, 0])
    splits: dict[str, list[dict]] = {"train": [], "test": []}
    with new_folder(out_dir) as folder:
        for split in splits:
            (folder / split).mkdir()

        def write(split: str, camera: Camera, view: ViewRenderer, t: int) -> None:
            image = view.render(parts, BodyPose(poses.rotations[t], poses.origins[t]))
            name = f"{split}/{camera.name}_{t:04d}.png"
            rgba = np.dstack([image.rgb[..., ::-1], image.mask * 255]).astype(np.uint8)
            if not cv2.imwrite(str(folder / name), rgba):
                raise RuntimeError(f"image {folder / name}: OpenCV could not write it")
            splits[split].append({"file_path": name, "time": float(times[t]), "transform_matrix": transform_matrix(camera)})

        for t in tqdm(range(config.frames), desc="synth: frames", unit="frame", disable=not progress):
            write("train", orbit[t], ViewRenderer(orbit[t], config.samples, None), t)
            if t % heldout_every == 0:
                for camera, view in zip(fixed, fixed_views):
                    write("test", camera, view, t)
        for split, frames in splits.items():
            document = {"camera_angle_x": float(angle), "frames": frames,
                        "generator": "mmcsplat synth --monocular", "seed": config.seed, "fps": config.fps, "turns": turns}
            (folder / f"transforms_{split}.json").write_text(json.dumps(document, indent=1))
    return MonocularResult(Path(out_dir), len(splits["train"]), len(splits["test"]), time.perf_counter() - started)
