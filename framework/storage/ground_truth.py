"""The ground truth a synthetic capture ships beside its videos (``mmcsplat synth``, docs/synthetic.md):
``CAPTURE/ground_truth.zarr``, named and read here only. The synthesizer writes it; ingest attaches its
masks and depth to the frames, evaluation follows its surface points, the ``synthetic`` landmark source
reads its joints. It lives in storage so that dataset and landmark plugins read it through the public API.

The group holds ``surface_points`` [T, P, 3] and ``joints`` [T, J, 3] (world metres, at the capture's
frames; their ``surface_point_parts`` and ``joint_names`` as attributes), and ``masks/CAMERA`` and
``depth/CAMERA`` [T, H, W] in the videos' pixels; its attributes hold ``fps``, ``num_frames`` and ``seed``.
Every array is read on first use, so a ground truth holding only some of them serves those.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError

if TYPE_CHECKING:
    from mmcsplat.storage.session import SessionReader

GROUND_TRUTH = "ground_truth.zarr"

Frames = int | slice | Sequence[int] | np.ndarray


class GroundTruthFrameError(InputError, IndexError):
    """A frame past the end of the ground truth."""


def ground_truth_beside(session: SessionReader) -> Path | None:
    """``SOURCE/ground_truth.zarr`` when the session was ingested from a capture that ships one."""
    if not session.source:
        return None
    candidate = Path(session.source) / GROUND_TRUTH
    return candidate if candidate.is_dir() else None


def ground_truth_gone(session: SessionReader) -> Path | None:
    """The ground truth the session's capture shipped at ingest (recorded in its provenance) when it is no
    longer there: the capture was moved or deleted, and tracking cannot be scored without ``--ground-truth``."""
    recorded = session.provenance.get("reader", {}).get("ground_truth")
    if not recorded or Path(recorded).is_dir():
        return None
    return Path(recorded)


class GroundTruthReader:
    """A capture's ground truth, opened from the capture folder or from the zarr group itself. ``frames`` are a frame index (→ [P, 3]), a slice or a sequence of indices (→ [T', P, 3])."""

    def __init__(self, path: str | Path) -> None:
        import zarr

        path = Path(path)
        self.path = path / GROUND_TRUTH if (path / GROUND_TRUTH).exists() else path
        if not self.path.exists():
            raise MissingFileError(f"synthetic ground truth {self.path} not found")
        try:
            self.group = zarr.open_group(str(self.path), mode="r")
        except Exception as error:
            raise InputError(f"{self.path}: not a ground truth, not a readable zarr group ({error})") from error

    @property
    def identity(self) -> str:
        """A 128-bit BLAKE2b digest of the group's attributes (the synthesizer's configuration, seed, frame
        times and scene): ingest records it, so that another capture's ground truth is never scored against."""
        text = json.dumps(self.group.attrs.asdict(), sort_keys=True, default=str)
        return hashlib.blake2b(text.encode(), digest_size=16).hexdigest()

    def require_truth_of(self, session: SessionReader) -> None:
        """Refuse this ground truth for ``session`` when the session was ingested from a capture whose
        ground truth was another (sessions ingested before identities were recorded are not checked)."""
        reader = session.provenance.get("reader", {})
        recorded = reader.get("ground_truth_identity")
        if recorded is not None and recorded != self.identity:
            raise InputError(f"{self.path} is the ground truth of another capture than session {session.url} was ingested from "
                             f"({reader.get('ground_truth')}): give that capture's ground_truth.zarr")

    def attribute(self, name: str) -> Any:
        """The group attribute ``name`` (``fps``, ``num_frames``, ``seed``)."""
        try:
            return self.group.attrs[name]
        except KeyError:
            raise InputError(f"{self.path}: not a synthetic ground truth (no attribute {name!r})") from None

    def points(self, name: str, frames: Frames = slice(None), needed_by: str = "so no frame") -> np.ndarray:
        """``surface_points`` or ``joints`` at ``frames``, float64 world metres; a frame past the end is an
        error ending in ``needed_by`` and the frame (e.g. "the tracks need frame 7")."""
        array = self.array(name)
        if array.ndim != 3 or array.shape[2] != 3:
            raise InputError(f"{self.path}: {name} must be [T, P, 3], got {list(array.shape)}")
        if isinstance(frames, slice):
            return np.asarray(array[frames], dtype=np.float64)
        single = isinstance(frames, (int, np.integer))
        indices = [int(frames)] if single else [int(t) for t in frames]
        late = [t for t in indices if not 0 <= t < array.shape[0]]
        if late:
            raise GroundTruthFrameError(f"{self.path}: ground truth has {array.shape[0]} frames, {needed_by} {late[0]}")
        values = np.asarray(array.oindex[indices], dtype=np.float64) if indices else np.zeros((0, *array.shape[1:]))
        return values[0] if single else values

    def names(self, name: str) -> list[str]:
        """The names of ``joints`` (``joint_names``) or ``surface_points`` (``surface_point_parts``)."""
        key = {"joints": "joint_names", "surface_points": "surface_point_parts"}[name]
        try:
            return list(self.array(name).attrs[key])
        except KeyError:
            raise InputError(f"{self.path}: {name} has no {key}") from None

    def array(self, name: str):
        """The zarr array ``name`` (e.g. ``joints``, ``masks/cam_0``); an error naming the file when absent."""
        try:
            return self.group[name]
        except KeyError:
            raise InputError(f"{self.path}: not a ground truth with a {name} array") from None

    def has(self, name: str) -> bool:
        """Whether the group holds ``name``."""
        return name in self.group
