"""Checkpoint and resume of a training state: written atomically, read back only by a run with the same
key (the configuration or settings and the data it trained on), so a killed training resumes to the same
result and a changed one never silently continues another's."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import atomic_path, disk_full


class CheckpointError(InputError):
    """A checkpoint that cannot be resumed: unreadable, or written by another run."""


#: How torch's zip writer reports a write the file system cut short (it hides the errno).
SHORT_WRITE = ("unexpected pos", "failed writing", "file write failed")


def save_checkpoint(path: Path, key: Any, state: dict[str, Any]) -> None:
    """Write ``state`` with the ``key`` a resuming run must match, atomically; a full disk is a
    :class:`~mmcsplat.storage.atomic.DiskFullError` and the previous checkpoint is kept."""
    try:
        with atomic_path(path) as temporary:
            torch.save({"key": key, **state}, temporary)
    except RuntimeError as error:
        if any(text in str(error) for text in SHORT_WRITE):
            raise disk_full(Path(path), error) from error
        raise


def read_checkpoint(path: Path) -> dict[str, Any]:
    """The whole payload of the checkpoint at ``path``; an error naming the file when it is unreadable."""
    try:
        return torch.load(path, weights_only=False)
    except Exception as error:  # torch raises RuntimeError, EOFError, pickle errors… for a damaged file
        raise CheckpointError(f"{path} is damaged or not a checkpoint ({error}); delete it to start afresh") from error


def resume_checkpoint(path: Path, key: Mapping[str, Any], fresh: str) -> dict[str, Any]:
    """The state saved at ``path``, when it was saved with ``key`` (a table of what the training depends on:
    settings, session, cameras, frames); otherwise an error naming the entries that differ and saying how
    to start ``fresh``."""
    payload = read_checkpoint(path)
    saved = payload.get("key")
    if saved != key:
        differing = sorted(name for name in key if not isinstance(saved, Mapping) or saved.get(name) != key[name])
        what = f"its {', '.join(differing)}" if differing and isinstance(saved, Mapping) else "it was written by an older mmcsplat, or its settings"
        raise CheckpointError(f"{path}: {what} differ from this run's; {fresh}")
    return payload

