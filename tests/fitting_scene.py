"""A tiny self-consistent capture for trainer tests: known Gaussians rendered by torch-reference into a
ring of cameras and written to a session store (masks from alpha, depth from the renderer). With
``frames`` > 1 the subject moves (see :func:`moved`), and :func:`write_ground_truth` stores its Gaussians'
centres as the surface points a tracking evaluation compares against."""

from __future__ import annotations

from pathlib import Path

import attrs
import numpy as np
import pytest
import torch

from mmcsplat.plugin_api.interfaces import SceneContext
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.scene.camera import Camera, look_at
from mmcsplat.storage.session import SessionReader, SessionWriter

WIDTH, HEIGHT, FOCAL = 48, 36, 40.0


def ring_camera(name: str, angle: float, radius: float = 1.2, height: float = 0.8, zoom: int = 1) -> Camera:
    """A camera on a ring around the origin, looking at it; ``zoom`` multiplies its resolution."""
    center = np.array([radius * np.cos(angle), radius * np.sin(angle), height])
    R = look_at(center, np.zeros(3))
    width, height, focal = WIDTH * zoom, HEIGHT * zoom, FOCAL * zoom
    K = [[focal, 0, width / 2 - 0.5], [0, focal, height / 2 - 0.5], [0, 0, 1]]
    return Camera(name, width, height, K, R, -R @ center)


def subject(count: int = 150, seed: int = 0, scale: float = 0.03) -> Gaussians:
    """``count`` Gaussians of ``scale`` metres with random colours and rotations in a 24 × 12 × 8 cm cloud."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(count, 3, generator=g, dtype=torch.float64) * torch.tensor([0.12, 0.06, 0.04], dtype=torch.float64)
    quats = torch.randn(count, 4, generator=g, dtype=torch.float64)
    log_scales = torch.full((count, 3), float(np.log(scale)), dtype=torch.float64)
    opacity_logits = torch.full((count,), 2.0, dtype=torch.float64)
    colors = torch.rand(count, 3, generator=g, dtype=torch.float64)
    return Gaussians(means, quats, log_scales, opacity_logits, colors, torch.ones(count, 1, dtype=torch.float64))


def single_precision(gaussians: Gaussians) -> Gaussians:
    """``gaussians`` in float32, as a trainer holds them (:func:`subject` is float64)."""
    return Gaussians(*(getattr(gaussians, field).float() for field in ("means", "quats", "log_scales", "opacity_logits", "colors", "features")))


def moved(gaussians: Gaussians, t: int, step: float = 0.005, bend: float = 0.04) -> Gaussians:
    """The subject at frame ``t``: translated ``step`` metres per frame along x, its x > 0 half bent
    ``t·bend`` radians about the y axis through the origin, smoothly (an articulated limb on a body)."""
    from mmcsplat.scene.quaternions import quat_multiply

    means = gaussians.means
    angle = t * bend * torch.clamp(means[:, 0] / 0.05, 0, 1)
    cos, sin = torch.cos(angle), torch.sin(angle)
    x, y, z = means.unbind(-1)
    bent = torch.stack([cos * x + sin * z, y, -sin * x + cos * z], dim=-1)
    half = torch.stack([torch.cos(angle / 2), torch.zeros_like(angle), torch.sin(angle / 2), torch.zeros_like(angle)], dim=-1)
    quats = quat_multiply(half, gaussians.quats / gaussians.quats.norm(dim=-1, keepdim=True))
    shift = torch.tensor([step * t, 0.0, 0.0], dtype=means.dtype)
    return Gaussians(bent + shift, quats, gaussians.log_scales, gaussians.opacity_logits, gaussians.colors, gaussians.features)


def write_session(path: Path, cameras: int = 5, heldout: tuple[str, ...] = ("cam_0",), blank: tuple[str, ...] = (),
                  frames: int = 1, absent: tuple[tuple[str, int], ...] = (), zoom: int = 1, truth: Gaussians | None = None,
                  masks: bool = True, depth: bool = True, plates: bool = False, supersample: int = 1, taller: tuple[str, ...] = (),
                  unmasked: tuple[str, ...] = (), provenance: dict | None = None) -> Path:
    """Render ``truth`` (default ``subject()``), moving over ``frames``, into ``cameras`` ring cameras of ``zoom`` times the
    base resolution; cameras in ``blank`` get an empty image/mask; the (camera, frame) pairs in ``absent``
    are left out of the session; ``masks`` / ``depth`` false leave those fields out (a capture without them),
    cameras in ``unmasked`` have no masks;
    with ``plates`` the subject is seen in front of each camera's :func:`plate` (else black), stored as its
    clean plate; ``supersample`` > 1 makes each pixel the mean of that many sub-pixels per side (a pixel
    integrating over its area); cameras in ``taller`` have two more rows (as a real rig's 1088-row cameras
    beside 1080-row ones); ``provenance`` is stored as the session's (``frames``: the capture frames ingest took)."""
    from mmcsplat.backends.torch_reference import TorchReferenceRenderer
    from mmcsplat.training.supersampling import supersampled

    renderer = supersampled(TorchReferenceRenderer(), supersample)
    rig = [ring_camera(f"cam_{i}", 2 * np.pi * i / cameras, zoom=zoom) for i in range(cameras)]
    rig = [attrs.evolve(c, height=c.height + 2, K=c.K + np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]])) if c.name in taller else c for c in rig]
    with SessionWriter(path, cameras=rig, num_frames=frames, fps=30.0, heldout=heldout, source="fitting-scene",
                       provenance=provenance) as writer:
        for t in range(frames):
            gaussians = moved(subject() if truth is None else truth, t)
            for camera in (camera for camera in rig if (camera.name, t) not in absent):
                out = renderer.render(gaussians, RenderCameras.from_cameras([camera], dtype=torch.float64))
                colour = out.rgb[0].numpy()
                if plates:
                    colour = colour + (1 - out.alpha[0].numpy())[..., None] * plate(camera) / 255.0
                rgb = (np.clip(colour, 0, 1) * 255).round().astype(np.uint8)
                mask = out.alpha[0].numpy() > 0.5
                if camera.name in blank:
                    rgb[:] = 0
                    mask[:] = False
                writer.write_frame(camera.name, t, rgb, mask=mask if masks and camera.name not in unmasked else None,
                                   depth=out.depth[0].numpy().astype(np.float32) if depth else None)
        if plates:
            for camera in rig:
                writer.write_plate(camera.name, plate(camera))
    return path


def plate(camera: Camera) -> np.ndarray:
    """[H, W, 3] uint8: a camera's empty scene for :func:`write_session` — checks of 4 px over a colour
    ramp, different in every camera."""
    v, u = np.mgrid[: camera.height, : camera.width]
    checks = ((u // 4 + v // 4) % 2)[..., None] * 0.3
    ramp = np.stack([u / camera.width, v / camera.height, np.full(u.shape, 0.5 + 0.05 * int(camera.name.split("_")[-1]))], axis=-1)
    return np.round(np.clip(0.2 + 0.5 * ramp + checks, 0, 1) * 255).astype(np.uint8)


def scene_context(session: SessionReader, frame: int = 0) -> SceneContext:
    """What a first-frame fit of ``session`` shows its initializers: its training cameras (the session's
    held-out ones left out) and the calibration's centre and scale, built as :class:`~mmcsplat.pipeline.fit.FirstFrameFit` does."""
    from mmcsplat.pipeline.fit import select_cameras
    from mmcsplat.scene.rig import rig_center, rig_scale

    train, _ = select_cameras(session, None)
    center = rig_center(session.cameras)
    return SceneContext(session, tuple(train), frame, center, rig_scale(session.cameras, center))


def write_ground_truth(path: Path, frames: int, truth: Gaussians | None = None) -> Path:
    """A ground-truth group with ``surface_points`` [T, P, 3]: the moving subject's Gaussian centres."""
    truth = subject() if truth is None else truth
    import zarr

    points = np.stack([moved(truth, t).means.numpy() for t in range(frames)]).astype(np.float32)
    zarr.open_group(str(path), mode="w", zarr_format=3).create_array("surface_points", data=points)
    return path


def write_fitted_run(run: Path, session: Path, truth: Gaussians | None = None, background: str | None = None,
                     supersample: int | None = None) -> Path:
    """A completed first-frame "fit" of ``session`` that is the true subject (default ``subject()``) at
    frame 0: tracking tests start from it, so what they measure is the dynamics alone. Its configuration
    has no segmentation loss: the true Gaussians' soft edges are not the optimum of one against binary
    masks, so it would move them even where nothing moves. ``background`` and ``supersample`` set those
    ``[fit]`` values."""
    import json

    from mmcsplat.scene.rig import rig_center, rig_scale
    from mmcsplat.training.model import GaussianModel, LearningRates

    reader = SessionReader(session)
    train = list(reader.train_cameras)
    truth = subject() if truth is None else truth
    gaussians = single_precision(truth)
    center = rig_center(reader.cameras)
    model = GaussianModel(gaussians, tuple(train), LearningRates(), rig_scale(reader.cameras, center))
    run.mkdir(parents=True, exist_ok=True)
    torch.save({"model": model.state_dict()}, run / "checkpoint.pt")
    fit = {"lambda_seg": 0.0, **({"background": background} if background is not None else {}),
           **({"supersample": supersample} if supersample is not None else {})}
    config = {"fit": fit, "renderer": {"name": "torch-cpu"}, "initializer": [{"name": "masked"}]}
    info = {
        "status": "complete", "session": str(Path(session).resolve()), "config": "test", "config_values": config,
        "renderer": "torch-cpu", "frame": 0, "train_cameras": train, "heldout_cameras": list(reader.heldout),
        "iterations": 0, "num_gaussians": gaussians.count, "wall_s": 0.0,
        "scene_center": center.tolist(), "scene_scale": rig_scale(reader.cameras, center), "recording": reader.fingerprint,
    }
    (run / "run.json").write_text(json.dumps(info))
    return run


CONFIG = """
[fit]
iterations = {iterations}
checkpoint_every = {checkpoint_every}
lambda_seg = 3.0
{background}
[renderer]
name = "torch-reference"

[[initializer]]
name = "random"
num_points = 200
half_size = 0.25

[[initializer]]
name = "masked"
radius = 2.0
every = 10

[densifier]
name = "default"
start = 10
stop = 35
every = 10
"""


def write_config(path: Path, iterations: int = 60, checkpoint_every: int = 20, background: str | None = None) -> Path:
    """:data:`CONFIG` with these settings (``background``: a ``fit.background`` TOML value)."""
    line = f"background = {background}\n" if background is not None else ""
    path.write_text(CONFIG.format(iterations=iterations, checkpoint_every=checkpoint_every, background=line))
    return path


def every_renderer() -> list:
    """Each registered renderer's name as a pytest parameter, skipped (saying why) where it is unusable."""
    from mmcsplat.configuration.registry import default_registry

    registry = default_registry()
    return [pytest.param(name, marks=pytest.mark.skipif(bool(reason := registry.get("renderer", name).unavailable_reason()), reason=str(reason)))
            for name in registry.names("renderer")]


def write_flow_session(path: Path, frames: int, truth: Gaussians) -> Path:
    """:func:`write_session` of ``truth`` (zoomed ×2) with its optical flow computed, for flow-guided tracking."""
    from mmcsplat.pipeline.flow import compute_flow

    session = write_session(path, frames=frames, zoom=2, truth=truth)
    compute_flow(session, progress=False)
    return session
