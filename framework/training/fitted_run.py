"""A run directory's first-frame fit, read once into one typed record: what tracking, evaluation,
landmarks, rendering, export, the viewer and the report read of a run.

It lives in ``training`` rather than beside the file names in :mod:`mmcsplat.storage.run` because reading
it needs the checkpoint reader and the backdrops of this room, which sits above ``storage``.
"""

from __future__ import annotations

import hashlib
from functools import cached_property
from pathlib import Path

import attrs
import torch

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.storage.recording import require_frames, require_same_recording
from mmcsplat.storage.run import CHECKPOINT, RUN_INFO
from mmcsplat.storage.run_info import RunInfo
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader

from .backdrop import Background, camera_backdrop, parse_background
from .checkpoint import read_checkpoint
from .settings import FitSettings


@attrs.frozen
class FittedRun:
    """The fit of run directory :attr:`path`: its run.json record, the fitted Gaussians' parameters and
    the training cameras' learnt colour correction (``rgb * camera_scale[i] + camera_offset[i]`` for
    training camera ``i``). The session and the settings are read on first use (export needs neither)."""

    path: Path
    info: RunInfo
    params: dict[str, torch.Tensor]
    camera_scale: torch.Tensor
    camera_offset: torch.Tensor

    @classmethod
    def load(cls, run: str | Path) -> FittedRun:
        """The fit in ``run``; an error naming the directory when it is not a fit run directory."""
        run = Path(run)
        checkpoint = run / CHECKPOINT
        if not (run / RUN_INFO).exists() or not checkpoint.exists():
            raise MissingFileError(f"{run} is not a fit run directory (needs {RUN_INFO} and {CHECKPOINT})")
        info = RunInfo.read(run)
        model = read_checkpoint(checkpoint)["model"]
        return cls(run, info, model["params"], model["camera_scale"], model["camera_offset"])

    def require_complete(self) -> None:
        """Refuse a fit that is still running or diverged: later steps need its final Gaussians."""
        if not self.info.complete:
            raise InputError(f"{self.path / RUN_INFO}: the first-frame fit is {self.info.status!r}, not complete: finish it with `mmcsplat fit` first")

    @cached_property
    def session(self) -> SessionReader:
        """The session the run was fitted on; refused when the store at its path now holds another
        recording (:func:`~mmcsplat.storage.recording.require_same_recording`)."""
        try:
            session = SessionReader(self.info.session)
        except FileNotFoundError as error:
            raise MissingFileError(f"{self.path}: its session {self.info.session} cannot be opened ({error}); moved or deleted? put the "
                                   f"session back at that path (the run is bound to it)") from error
        require_same_recording(self.path, self.info, session)
        require_frames(self.path, session, session.num_frames, self.info.frame + 1, f"it was fitted at frame {self.info.frame}")
        return session

    @cached_property
    def digest(self) -> str:
        """A 128-bit BLAKE2b digest of the fitted Gaussians' parameters: ``track`` records it in the tracks
        (``fit``), so that tracks are only ever read with the fit they start from."""
        digest = hashlib.blake2b(digest_size=16)
        for name in sorted(self.params):
            digest.update(name.encode())
            digest.update(self.params[name].detach().cpu().contiguous().reshape(-1).view(torch.uint8).numpy().tobytes())
        return digest.hexdigest()

    def require_tracked_frames(self, tracks: TrackReader) -> None:
        """Refuse the run's session unless it holds every frame of its ``tracks``."""
        first = int(tracks.attrs.get("first_frame", self.info.frame))
        require_frames(self.path, self.session, self.session.num_frames, first + tracks.num_frames,
                       f"tracked over frames {first}–{first + tracks.num_frames - 1}")

    def require_own_tracks(self, tracks: TrackReader) -> None:
        """Refuse ``tracks`` (read from this run) unless made on this run's recording from this fit: tracks
        copied from another run scored or rendered as this one's would be a silent wrong result. Tracks
        older than these records are not checked."""
        if tracks.fingerprint is not None:
            require_same_recording(self.path, self.info, tracks)
        if tracks.fit is not None and tracks.fit != self.digest:
            raise InputError(f"{tracks.path} were tracked from another fit than {self.path / CHECKPOINT} (copied from another run?): "
                             f"track the run again with `mmcsplat track {self.path} --overwrite`")

    @cached_property
    def settings(self) -> FitSettings:
        """The ``[fit]`` settings the run was fitted with."""
        return FitSettings.from_table(self.info.fit_table, str(self.path / RUN_INFO))

    @property
    def background(self) -> Background:
        """The ``fit.background`` the run was fitted with."""
        return parse_background(self.info.background_value)

    def backdrop(self, camera: str) -> torch.Tensor:
        """What ``camera``'s renders were composited over in the fit (:func:`~mmcsplat.training.backdrop.camera_backdrop`)."""
        return camera_backdrop(self.background, self.session, camera)
