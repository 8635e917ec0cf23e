"""A tiny tracked run for the render and export tests: the fitting scene's session, a few-iteration
first-frame fit with torch-reference, and tracks.zarr with synthetic motion (a drift along x plus a spin
about z that differs per Gaussian, so trails have shape)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from fitting_scene import write_config, write_session

from mmcsplat.configuration.config import load_config
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackWriter
from mmcsplat.training.fitted_run import FittedRun

FRAMES = 6
STATIC = ("log_scales", "opacity_logits", "color_logits", "seg_logits")


def synthetic_means(means: torch.Tensor, t: int) -> torch.Tensor:
    """The fitted ``means`` moved to frame ``t``: 1 cm per frame along x, 0.1 rad per frame about z."""
    angle = torch.tensor(0.1 * t)
    rotation = torch.tensor([[torch.cos(angle), -torch.sin(angle), 0.0], [torch.sin(angle), torch.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    return means @ rotation.T + torch.tensor([0.01 * t, 0.0, 0.0])


def fitted_run(root: Path, iterations: int = 3) -> Path:
    """``root``/run: a first-frame fit (no tracks) of a five-camera session (cam_0 held out) of :data:`FRAMES`
    frames, which :func:`add_tracks` may track (a run is refused with a session lacking its tracked frames)."""
    session = SessionReader(write_session(root / "session.zarr", frames=FRAMES))
    config = load_config(write_config(root / "fit.toml", iterations=iterations, checkpoint_every=iterations))
    run = root / "run"
    FirstFrameFit(session, config, run, backend="torch-reference", progress=False).run()
    return run


def add_tracks(run: Path, frames: int = FRAMES) -> Path:
    """Write ``run``/tracks.zarr: the fitted Gaussians moved by :func:`synthetic_means` over ``frames``."""
    params = FittedRun.load(run).params
    with TrackWriter(run, num_frames=frames, static={name: params[name] for name in STATIC}, method="synthetic",
                     attrs={"first_frame": 0}) as writer:
        for t in range(frames):
            writer.write_frame(t, means=synthetic_means(params["means"], t), quats=params["quats"])
    return run


def expected_means(run: Path, t: int) -> np.ndarray:
    """The means a reader of ``run``'s tracks must find at frame ``t``."""
    params = FittedRun.load(run).params
    return synthetic_means(params["means"], t).numpy()
