"""The Gaussians of a run directory frame by frame, whether or not it has been tracked: its tracks
(``RUN/tracks.zarr``) when present, else the first-frame fit as a one-frame sequence. Rendering and export
read runs through this."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.render_contract import Gaussians, gaussians_from_params
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.run import TRACKS_DIR
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader
from mmcsplat.training.backdrop import PLATE
from mmcsplat.training.fitted_run import FittedRun

FOREGROUND = 0.5  # segmentation colour above which a Gaussian belongs to the subject


class RunStates:
    """Frame ``k`` (0 ≤ k < :attr:`num_frames`) of a run is session frame :attr:`first_frame` + k."""

    def __init__(self, run: str | Path) -> None:
        self.run = Path(run)
        if not self.run.is_dir():
            raise MissingFileError(f"run directory {self.run} does not exist")
        self.fitted = FittedRun.load(self.run)
        self.info = self.fitted.info
        self.tracks = TrackReader(self.run) if (self.run / TRACKS_DIR).exists() else None
        if self.tracks is not None:
            self.fitted.require_own_tracks(self.tracks)
        self._fitted = None if self.tracks is not None else {name: value.detach().float() for name, value in self.fitted.params.items()}
        first = self.tracks.attrs.get("first_frame", self.info.frame) if self.tracks is not None else self.info.frame
        self.first_frame = int(first)

    @property
    def num_frames(self) -> int:
        return self.tracks.num_frames if self.tracks is not None else 1

    @property
    def session(self) -> SessionReader:
        """The session the run was fitted on (opened on first use: export does not need it), holding every
        tracked frame."""
        if self.tracks is not None:
            self.fitted.require_tracked_frames(self.tracks)
        return self.fitted.session

    def params(self, k: int) -> dict[str, torch.Tensor]:
        """Every ``GAUSSIAN_PARAMETERS`` tensor at frame ``k``."""
        if self.tracks is not None:
            return self.tracks.params(k)
        if k != 0:
            raise IndexError(f"{self.run} has no tracks: frame {k} does not exist (only the first-frame fit, frame 0)")
        return self._fitted

    def gaussians(self, k: int) -> Gaussians:
        """The renderable Gaussians at frame ``k``."""
        return gaussians_from_params(self.params(k))

    def means(self, k: int) -> np.ndarray:
        """[N, 3] Gaussian centres at frame ``k``."""
        return self.tracks.means(k) if self.tracks is not None else self._fitted["means"].numpy()

    def foreground(self) -> np.ndarray:
        """Indices of the subject's Gaussians (segmentation colour > 0.5 at frame 0)."""
        seg = torch.sigmoid(self.params(0)["seg_logits"][:, 0]).numpy()
        return np.flatnonzero(seg > FOREGROUND)

    @property
    def background(self) -> tuple[float, float, float]:
        """The background colour renders are shown over: the run's, or black for a run fitted over clean
        plates (a viewpoint between the cameras has no plate)."""
        background = self.fitted.background
        return (0.0, 0.0, 0.0) if background == PLATE else background

    @property
    def train_cameras(self) -> list[Camera]:
        return [self.session.camera(name) for name in self.info.train_cameras]

    def camera(self, name: str | None) -> Camera:
        """The session camera ``name``; by default the run's first held-out camera (else its first
        training camera)."""
        if name is None:
            name = (self.info.heldout_cameras or self.info.train_cameras)[0]
        if name not in self.session.camera_names:
            raise InputError(f"unknown camera {name!r}: session {self.info.session} has {list(self.session.camera_names)}")
        return self.session.camera(name)
