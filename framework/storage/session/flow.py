"""A session's optical flow: stored beside its images, written atomically and resumably, read pair by pair.

Layout (an optional part of a session; docs/session-store.md)::

    <session>/
        zarr.json           attribute ``flow``: {"group": "flow.<token>", "method": {...}, "cameras": [name]}
        flow.<token>/       one array per camera, [T-1, H, W, 6] float16, one pair of frames per chunk:
            <camera>            channels: forward (u, v) on frame t's pixels towards t+1, backward (u, v) on
                                frame t+1's pixels towards t, and the forward and backward confidences in [0, 1]

Pair ``t`` (frames t and t+1) is stored where the camera holds both frames. The flow depends on the
images, which nothing but a new ingest (a new session store) changes, and on the masks it was cut around
(its method record names them, so a new segmentation means recomputing); plates keep it. A
:class:`FlowWriter` writes into a new group no reader looks at and swaps it in with one write of the
session's attributes; interrupted, it leaves that group for the next writer of the same method, which
keeps the pairs already written (each pair is one chunk: it is either there and decodes, or is computed
again) and deletes groups of any other method.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.chunks import DamagedStoreError, open_stored, read_stored
from mmcsplat.storage.locking import session_lock
from mmcsplat.storage.transaction import Transaction

from .format import local_path
from .reader import SessionBase

#: The session attribute naming the committed flow.
FLOW = "flow"
#: Channels per pixel: forward u, v; backward u, v; forward confidence; backward confidence.
CHANNELS = 6
DTYPE = np.dtype(np.float16)


@attrs.frozen(eq=False)
class FlowPair:
    """The flow between frames t and t+1 of one camera, in pixels: ``forward`` [H, W, 2] moves frame t's pixel
    (u, v) to (u, v) + forward in frame t+1; ``backward`` [H, W, 2] moves frame t+1's pixels back to frame t;
    ``forward_confidence`` and ``backward_confidence`` [H, W] in [0, 1] say how well the two agree there."""

    forward: np.ndarray
    backward: np.ndarray
    forward_confidence: np.ndarray
    backward_confidence: np.ndarray

    def packed(self) -> np.ndarray:
        """[H, W, 6] in the stored channel order."""
        return np.concatenate(
            [self.forward, self.backward, self.forward_confidence[..., None], self.backward_confidence[..., None]], axis=-1
        )

    @classmethod
    def unpacked(cls, array: np.ndarray) -> FlowPair:
        """The pair from [H, W, 6] stored channels, as float32."""
        values = np.asarray(array, dtype=np.float32)
        return cls(values[..., 0:2], values[..., 2:4], values[..., 4], values[..., 5])


def pair_present(present: np.ndarray) -> np.ndarray:
    """[T-1] bool: the pairs (t, t+1) a camera holding frames ``present`` [T] has flow for."""
    present = np.asarray(present, dtype=bool)
    return present[:-1] & present[1:]


class SessionFlow(SessionBase):
    """The committed flow of a complete session, read lazily one pair at a time (:meth:`pair`).
    ``available`` is false for a session without flow (``mmcsplat flow SESSION`` computes it)."""

    def __init__(self, url: str | os.PathLike, *, storage_options: dict | None = None) -> None:
        super().__init__(url, "r", storage_options)
        record = self._attributes.get(FLOW)
        self.available = record is not None
        self.method: dict[str, Any] = dict(record["method"]) if record else {}
        self.cameras_with_flow: tuple[str, ...] = tuple(record["cameras"]) if record else ()
        self._group_name = record["group"] if record else None
        self._arrays: dict[str, Any] = {}

    def has(self, camera: str) -> bool:
        """Whether ``camera`` has flow."""
        self.camera(camera)
        return camera in self.cameras_with_flow

    def pair(self, t: int, camera: str) -> FlowPair:
        """The flow between frames ``t`` and ``t + 1`` of ``camera``; an error naming the camera and frame
        when it has none there."""
        if not self.has(camera):
            raise InputError(f"{self.url}: camera {camera!r} has no optical flow; compute it with `mmcsplat flow {self.url}`")
        if not 0 <= t < self.num_frames - 1 or not pair_present(self.present(camera))[t]:
            raise InputError(f"{self.url}: camera {camera!r} has no flow from frame {t} to {t + 1} (the session lacks one of them)")
        if camera not in self._arrays:
            self._arrays[camera] = open_stored(self._group, f"{self._group_name}/{camera}", f"session {self.url}: flow")
        return FlowPair.unpacked(read_stored(self._arrays[camera], t, f"session {self.url}: camera {camera!r} flow, frames {t}–{t + 1}"))


class FlowWriter(SessionBase, Transaction):
    """Writes the flow of ``cameras`` of a complete session, made by ``method`` (a JSON record of how), and
    commits it in one attribute write, replacing any flow the session had. Resumes the pending group an
    interrupted writer of the same ``method`` and cameras left (:meth:`done` says which pairs it holds);
    :meth:`commit` refuses unless every pair of present frames is written. One writer of a local session at
    a time (the session's writer lock)."""

    def __init__(self, url: str | os.PathLike, *, method: Mapping[str, Any], cameras: Sequence[str], storage_options: dict | None = None) -> None:
        target = local_path(url)
        self._lock = session_lock(target) if target is not None else None
        try:
            super().__init__(url, "r+", storage_options)
            if self.num_frames < 2:
                raise InputError(f"{self.url}: a session of one frame has no optical flow")
            for camera in cameras:
                self.camera(camera)
            self.method = dict(method)
            self.flow_cameras = tuple(cameras)
            self._pending_name = self._resume_or_create()
        except BaseException:
            self._release()
            raise
        self._pending = self._group[self._pending_name]
        self._written = {camera: self._stored_pairs(camera) for camera in self.flow_cameras}

    def _resume_or_create(self) -> str:
        """The pending group to write into: a matching one left by an interrupted writer, or a new one;
        other uncommitted flow groups are deleted."""
        committed = (self._attributes.get(FLOW) or {}).get("group")
        wanted = {"method": self.method, "cameras": list(self.flow_cameras)}
        resumed = None
        for name in list(self._group.group_keys()):
            if not name.startswith(f"{FLOW}.") or name == committed:
                continue
            if resumed is None and self._group[name].attrs.asdict() == wanted:
                resumed = name
            else:
                del self._group[name]
        if resumed is not None:
            return resumed
        name = f"{FLOW}.{uuid.uuid4().hex[:8]}"
        group = self._group.create_group(name)
        group.attrs.update(wanted)
        for camera in self.flow_cameras:
            self._create_array(group, camera)
        return name

    def _create_array(self, group: Any, camera: str) -> None:
        from zarr.codecs import ZstdCodec

        spec = self.camera(camera)
        shape = (self.num_frames - 1, spec.height, spec.width, CHANNELS)
        group.create_array(camera, shape=shape, chunks=(1, *shape[1:]), dtype=DTYPE, compressors=[ZstdCodec(level=1)],
                           chunk_key_encoding={"name": "default", "separator": "."}, config={"write_empty_chunks": True})

    def _stored_pairs(self, camera: str) -> np.ndarray:
        """[T-1] bool: the pairs of ``camera`` already in the pending group whose chunk decodes."""
        array = self._pending[camera]
        stored = np.zeros(self.num_frames - 1, dtype=bool)
        for t in np.flatnonzero(pair_present(self.present(camera))):
            try:
                read_stored(array, int(t), "resumed flow")
                stored[t] = True
            except DamagedStoreError:
                pass  # not written yet, or cut off mid-write: computed again
        return stored

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()

    def done(self, camera: str, t: int) -> bool:
        """Whether the pair (t, t+1) of ``camera`` is already written (by this writer or the one it resumes)."""
        return bool(self._written[camera][t])

    def write(self, camera: str, t: int, pair: FlowPair) -> None:
        """Store the flow of ``camera`` between frames ``t`` and ``t + 1``."""
        self._check_open()
        spec = self.camera(camera)
        packed = pair.packed()
        if packed.shape != (spec.height, spec.width, CHANNELS) or not np.isfinite(packed).all():
            raise InputError(f"{self.url}: camera {camera!r} flow of frames {t}–{t + 1} must be finite [{spec.height}, {spec.width}] fields, "
                             f"got {list(packed.shape[:2])}")
        self._pending[camera][t] = packed.astype(DTYPE)
        self._written[camera][t] = True

    def missing(self, camera: str) -> np.ndarray:
        """The pairs of ``camera`` still to write."""
        return np.flatnonzero(pair_present(self.present(camera)) & ~self._written[camera])

    def commit(self) -> None:
        """Make the flow the session's, replacing the flow it had; refuses while pairs are missing."""
        self._check_open()
        gaps = {camera: self.missing(camera) for camera in self.flow_cameras}
        gaps = {camera: pairs for camera, pairs in gaps.items() if len(pairs)}
        if gaps:
            self.abort()
            shown = "; ".join(f"camera {camera!r}: {len(pairs)} pair(s) from frame {pairs[0]}" for camera, pairs in gaps.items())
            raise InputError(f"{self.url}: the flow is incomplete ({shown}); run `mmcsplat flow` again to finish it")
        replaced = (self._attributes.get(FLOW) or {}).get("group")
        self._group.attrs.update({FLOW: {"group": self._pending_name, "method": self.method, "cameras": list(self.flow_cameras)}})
        self._done = True
        try:
            if replaced is not None and replaced != self._pending_name:
                del self._group[replaced]
        finally:
            self._release()

    def abort(self) -> None:
        """Stop without committing: the session is left as it was, and the pairs written stay for the next
        writer of the same method to resume."""
        if self._done:
            return
        self._done = True
        self._release()
