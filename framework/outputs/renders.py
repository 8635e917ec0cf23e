"""Videos of a run (``mmcsplat render``): a novel-view loop around the rig, the reference study's tracking
figure, and expected depth. Each frame is rendered on demand and streamed to :func:`mmcsplat.outputs.video.write_video`.

Frames: a run with tracks has T frames (frame k is session frame ``first_frame + k``); without tracks it
is its first-frame fit, one frame. Fixed-camera outputs (trajectories, depth) have one video frame per run
frame. The novel-view path has its own length (ring cameras × frames per segment); its frame j shows the
Gaussians of run frame ``j mod T``: the motion loops while the camera goes round, and the default frames
per segment make the path at least as long as the sequence, so every frame is shown.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.outputs.camera_path import camera_path
from mmcsplat.outputs.video import write_png, write_video
from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import NEAR_PLANE, RenderCameras, RenderOutput
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.run import NOVEL_VIDEO
from mmcsplat.training.supersampling import run_renderer

MIN_FRAMES_PER_SEGMENT = 15
TRAJECTORY_FRACTION = 0.02  # of the foreground Gaussians, as in the study's figure
TRAIL_FRAMES = 10
STRIP_FRAMES = 5
DEPTH_PERCENTILES = (1.0, 99.0)  # of visible Gaussian centres' depths: floaters do not stretch the range
DEPTH_COLORMAP = "turbo"
_GOLDEN = 0.6180339887498949  # hue step: neighbouring indices get far-apart colours


class RunRenderer:
    """Renders one run's Gaussians with one renderer backend (default: the one that fitted the run)."""

    def __init__(self, states: RunStates, backend: str | None = None, scale: float = 1.0,
                 registry: Registry | None = None, progress: bool = True) -> None:
        if scale <= 0:
            raise InputError(f"render scale must be positive, got {scale}")
        self.states = states
        self.scale = scale
        self.progress = progress
        self.renderer: Renderer = run_renderer(states.info, registry or default_registry(), backend)
        self.background = torch.tensor(states.background, dtype=torch.float32)

    def scaled(self, camera: Camera) -> Camera:
        """``camera`` at the output scale."""
        return camera if self.scale == 1 else camera.scaled(self.scale)

    def render(self, k: int, camera: Camera) -> RenderOutput:
        """Run frame ``k`` seen by ``camera`` (already scaled)."""
        with torch.no_grad():
            return self.renderer.render(self.states.gaussians(k), RenderCameras.from_cameras([camera]), self.background)

    def frames(self, description: str, count: int) -> Iterator[int]:
        """``range(count)`` with a progress bar."""
        from tqdm import tqdm

        yield from tqdm(range(count), desc=description, unit="frame", disable=not self.progress)


def to_uint8(rgb: torch.Tensor) -> np.ndarray:
    """A [H, W, 3] image in [0, 1] as uint8."""
    return (rgb.clamp(0, 1) * 255).round().to(torch.uint8).numpy()


# ------------------------------------------------------------------------------------------ novel view


def default_frames_per_segment(num_frames: int, num_cameras: int) -> int:
    """Enough path frames to show every run frame once, and at least a smooth MIN_FRAMES_PER_SEGMENT."""
    return max(MIN_FRAMES_PER_SEGMENT, math.ceil(num_frames / num_cameras))


def render_novel(renderer: RunRenderer, out: Path, frames_per_segment: int | None = None) -> Path:
    """``out``/novel.mp4: the camera path through the training cameras (module docstring)."""
    states = renderer.states
    cameras = states.train_cameras
    per_segment = frames_per_segment or default_frames_per_segment(states.num_frames, len(cameras))
    path = [renderer.scaled(camera) for camera in camera_path(cameras, per_segment)]

    def frames() -> Iterator[np.ndarray]:
        for j in renderer.frames("novel view", len(path)):
            yield to_uint8(renderer.render(j % states.num_frames, path[j]).rgb[0])

    target = out / NOVEL_VIDEO
    write_video(target, frames(), states.session.fps)
    return target


# ---------------------------------------------------------------------------------------- trajectories


def trajectory_gaussians(states: RunStates, fraction: float = TRAJECTORY_FRACTION, seed: int = 0) -> np.ndarray:
    """Sorted indices of ``fraction`` of the foreground Gaussians (of all, when none is foreground), at
    least one, drawn with ``seed``: the same run gives the same choice."""
    candidates = states.foreground()
    if not len(candidates):
        candidates = np.arange(states.params(0)["means"].shape[0])
    count = max(1, round(fraction * len(candidates)))
    return np.sort(np.random.default_rng(seed).choice(candidates, size=count, replace=False))


def trajectory_colors(indices: np.ndarray) -> np.ndarray:
    """[n, 3] uint8 RGB, one saturated colour per Gaussian index, a function of the index alone."""
    from matplotlib.colors import hsv_to_rgb

    hue = (np.asarray(indices, dtype=np.float64) * _GOLDEN) % 1.0
    hsv = np.stack([hue, np.full_like(hue, 0.85), np.ones_like(hue)], axis=-1)
    return (hsv_to_rgb(hsv) * 255).round().astype(np.uint8)


def project_visible(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixels [N, 2], in front [N] bool) of world ``points`` [N, 3] in a pinhole ``camera``."""
    depth = (points @ camera.R.T + camera.t)[:, 2]
    return camera.project(points), depth > NEAR_PLANE


def draw_trails(image: np.ndarray, trails: np.ndarray, valid: np.ndarray, colors: np.ndarray, thickness: int | None = None) -> np.ndarray:
    """``image`` with one polyline per Gaussian through its pixel positions ``trails`` [L, n, 2] (oldest
    first; positions not ``valid`` [L, n] break the trail off) and a dot at the newest one; lines
    ``thickness`` pixels wide (default: in proportion to the image)."""
    import cv2

    image = np.ascontiguousarray(image).copy()
    thickness = thickness or max(1, round(min(image.shape[:2]) / 300))
    # cv2's shift=4 sub-pixel coordinates; clipped so centres near the camera plane do not overflow int32
    fixed = np.round(np.clip(trails, -1e5, 1e5) * 16).astype(np.int32)
    for i, color in enumerate(colors.tolist()):
        recent = fixed[:, i][np.cumprod(valid[::-1, i])[::-1].astype(bool)]  # the unbroken tail
        if len(recent) > 1:
            cv2.polylines(image, [recent], False, color, thickness, cv2.LINE_AA, shift=4)
        if len(recent):
            cv2.circle(image, tuple(recent[-1]), 16 * (thickness + 1), color, -1, cv2.LINE_AA, shift=4)
    return image


def strip_frames(num_frames: int, count: int = STRIP_FRAMES) -> np.ndarray:
    """Up to ``count`` evenly spaced frame indices from first to last."""
    return np.unique(np.linspace(0, num_frames - 1, count).round().astype(int))


def render_trajectories(renderer: RunRenderer, out: Path, camera: str | None = None) -> tuple[Path, Path]:
    """``out``/trajectories_CAMERA.mp4 and .png: the study's tracking figure — 2 % of the foreground
    Gaussians, each with its trail over the last TRAIL_FRAMES frames in its own colour, over the rendered
    image of ``camera`` (default: the held-out one) — and a strip of STRIP_FRAMES of its frames."""
    states = renderer.states
    view = renderer.scaled(states.camera(camera))
    chosen = trajectory_gaussians(states)
    colors = trajectory_colors(chosen)
    history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=TRAIL_FRAMES)
    in_strip = set(strip_frames(states.num_frames).tolist())
    strip: list[np.ndarray] = []

    def frames() -> Iterator[np.ndarray]:
        for k in renderer.frames(f"trajectories ({view.name})", states.num_frames):
            history.append(project_visible(view, states.means(k)[chosen].astype(np.float64)))
            pixels, valid = (np.stack(part) for part in zip(*history, strict=True))
            image = draw_trails(to_uint8(renderer.render(k, view).rgb[0]), pixels, valid, colors)
            if k in in_strip:
                strip.append(image)
            yield image

    video = out / f"trajectories_{view.name}.mp4"
    write_video(video, frames(), states.session.fps)
    png = out / f"trajectories_{view.name}.png"
    write_png(png, np.concatenate(strip, axis=1))
    return video, png


# ----------------------------------------------------------------------------------------------- depth


def depth_range(states: RunStates, camera: Camera) -> tuple[float, float]:
    """(near, far) metres for the whole sequence in ``camera``: percentiles of the depths of the Gaussian
    centres (foreground ones when there are) it sees, the lowest and highest over frames."""
    index = states.foreground()
    near, far = math.inf, -math.inf
    for k in range(states.num_frames):
        means = states.means(k)
        points = (means[index] if len(index) else means).astype(np.float64)
        pixels, front = project_visible(camera, points)
        inside = front & np.all((pixels >= -0.5) & (pixels < [camera.width - 0.5, camera.height - 0.5]), axis=1)
        if inside.any():
            depth = (points[inside] @ camera.R.T + camera.t)[:, 2]
            low, high = np.percentile(depth, DEPTH_PERCENTILES)
            near, far = min(near, low), max(far, high)
    if not math.isfinite(near):
        raise InputError(f"camera {camera.name!r} sees none of the run's Gaussians in any frame: no depth to render")
    return near, max(far, near + 1e-3)


def colorize_depth(depth: np.ndarray, alpha: np.ndarray, near: float, far: float, colormap: str = DEPTH_COLORMAP) -> np.ndarray:
    """[H, W] expected depth → uint8 RGB through ``colormap`` over [near, far], faded to black where the
    Gaussians' ``alpha`` [H, W] is low (nothing drawn there)."""
    from matplotlib import colormaps

    normalized = np.clip((depth - near) / (far - near), 0.0, 1.0)
    rgb = colormaps[colormap](normalized)[..., :3] * np.clip(alpha, 0.0, 1.0)[..., None]
    return (rgb * 255).round().astype(np.uint8)


def render_depth(renderer: RunRenderer, out: Path, camera: str | None = None) -> tuple[Path, tuple[float, float]]:
    """``out``/depth_CAMERA.mp4: expected depth in ``camera`` (default: the held-out one), colour-mapped
    over one range for the whole sequence (:func:`depth_range`); returns the path and the range."""
    states = renderer.states
    view = renderer.scaled(states.camera(camera))
    near, far = depth_range(states, view)

    def frames() -> Iterator[np.ndarray]:
        for k in renderer.frames(f"depth ({view.name})", states.num_frames):
            render = renderer.render(k, view)
            yield colorize_depth(render.depth[0].numpy(), render.alpha[0].numpy(), near, far)

    target = out / f"depth_{view.name}.mp4"
    write_video(target, frames(), states.session.fps)
    return target, (near, far)
