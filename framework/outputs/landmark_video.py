"""The landmark overlay video (``mmcsplat render RUN --landmarks``): the carried landmarks of
``RUN/landmarks.csv`` and their trails over the last 10 frames, drawn on a real camera's images (the
held-out camera by default: what no training view saw), cropped to the subject and scaled up so a
clinician sees the limbs, not the room.

Crop: the box around every landmark's pixel over the whole sequence, grown by a quarter of its size on
each side, kept inside the image; the video is then scaled so its shorter side is at least 480 px.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np

from mmcsplat.outputs.renders import TRAIL_FRAMES, draw_trails, project_visible, trajectory_colors
from mmcsplat.outputs.video import write_video
from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import MissingFileError
from mmcsplat.storage.landmark_formats import read_landmark_csv
from mmcsplat.storage.run import LANDMARKS_CSV

MIN_SHORT_SIDE = 480  # pixels
MARGIN = 0.25  # of the landmarks' box, added on each side


def crop_box(pixels: np.ndarray, width: int, height: int, margin: float = MARGIN) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) around the finite ``pixels`` [..., 2], grown by ``margin`` of its size, in the image."""
    finite = pixels[np.all(np.isfinite(pixels), axis=-1)]
    inside = finite[(finite[:, 0] >= 0) & (finite[:, 0] < width) & (finite[:, 1] >= 0) & (finite[:, 1] < height)]
    if not len(inside):
        return 0, 0, width, height
    low, high = inside.min(axis=0), inside.max(axis=0)
    grow = np.maximum((high - low) * margin, 8.0)
    x0, y0 = np.maximum(np.floor(low - grow), 0).astype(int)
    x1, y1 = np.minimum(np.ceil(high + grow) + 1, [width, height]).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def render_landmarks(run: str | Path, out: str | Path, camera: str | None = None, progress: bool = True) -> Path:
    """Write ``out``/landmarks_CAMERA.mp4 (module docstring); returns its path."""
    import cv2
    from tqdm import tqdm

    states = RunStates(run)
    path = Path(run) / LANDMARKS_CSV
    if not path.is_file():
        raise MissingFileError(f"{path} does not exist: `mmcsplat landmarks {run} --source …` carries landmarks first")
    names, capture, _, positions, _ = read_landmark_csv(path)
    frames = states.session.session_frames(capture, str(path))
    view = states.camera(camera)
    present = states.session.present(view.name)
    projected = [project_visible(view, np.where(np.isfinite(points), points, 0.0)) for points in positions]
    pixels = np.stack([p for p, _ in projected])
    visible = np.stack([v for _, v in projected]) & np.all(np.isfinite(positions), axis=-1)
    x0, y0, x1, y1 = crop_box(np.where(visible[..., None], pixels, np.nan), view.width, view.height)
    factor = max(1.0, MIN_SHORT_SIDE / min(x1 - x0, y1 - y0))
    size = (int(round((x1 - x0) * factor)) // 2 * 2, int(round((y1 - y0) * factor)) // 2 * 2)
    colors = trajectory_colors(np.arange(len(names)))
    history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=TRAIL_FRAMES)

    def images():
        for k, t in enumerate(tqdm(frames, desc=f"landmarks ({view.name})", unit="frame", disable=not progress)):
            if not present[t]:
                history.clear()
                continue
            scaled = (pixels[k] - [x0, y0]) * [size[0] / (x1 - x0), size[1] / (y1 - y0)]
            history.append((scaled, visible[k]))
            crop = states.session.frame(int(t), view.name).rgb[y0:y1, x0:x1]
            image = cv2.resize(np.ascontiguousarray(crop), size, interpolation=cv2.INTER_CUBIC)
            trails, valid = (np.stack(part) for part in zip(*history, strict=True))
            yield draw_trails(image, trails, valid, colors, thickness=max(3, round(min(size) / 160)))

    video = Path(out) / f"landmarks_{view.name}.mp4"
    write_video(video, images(), states.session.fps)
    return video
