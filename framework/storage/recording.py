"""A run is bound to the recording it was fitted on: the session's fingerprint (the digest of its cameras,
frame times and every stored image, written at ingest) is recorded in run.json, in every checkpoint and
in the tracks store, and checked here wherever a command opens a run's session, so that a session
replaced at the same path (re-ingested, another infant) is never tracked, scored or rendered as the one
the run was fitted on."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Protocol

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.run_info import RunInfo


class RecordingMismatchError(InputError):
    """A run opened against a session (or tracks) of another recording than the one it was fitted on."""


class Recorded(Protocol):
    """What holds a recording's fingerprint: a session, or a run's tracks."""

    url: str

    @property
    def fingerprint(self) -> str | None: ...


def require_same_recording(run: Path, info: RunInfo, store: Recorded) -> None:
    """Refuse ``store`` (the session, or the tracks, opened for the run directory ``run`` whose run.json is
    ``info``) unless it holds the recording the run was fitted on. A run or session written before
    fingerprints existed cannot be checked: a warning says so."""
    if info.recording is None or store.fingerprint is None:
        older = f"run {run}" if info.recording is None else store.url
        warnings.warn(f"{older} was written before mmcsplat fingerprinted recordings: cannot check that {store.url} holds the "
                      f"recording {run} was fitted on", stacklevel=2)
        return
    if info.recording != store.fingerprint:
        raise RecordingMismatchError(f"run {run} was fitted on another recording than {store.url} holds (fingerprint "
                                     f"{info.recording[:12]}, found {store.fingerprint[:12]}): the recording differs — re-fit with a new --out")


def require_frames(run: Path, store: Recorded, num_frames: int, needed: int, what: str) -> None:
    """Refuse the session ``store`` of ``num_frames`` frames for the run directory ``run`` when the run needs
    frames 0 to ``needed`` − 1 (``what``: which of its work needs them). A session replaced at the run's
    path by a shorter recording is refused by its fingerprint; this names it for runs and sessions older
    than fingerprints, which would otherwise fail on an index out of bounds."""
    if needed > num_frames:
        raise RecordingMismatchError(f"session {store.url} has {num_frames} frame(s) but run {run} needs frames up to {needed - 1} "
                                     f"({what}): the session at that path is not the recording the run was fitted on — put that "
                                     "recording back there, or re-fit with a new --out")

