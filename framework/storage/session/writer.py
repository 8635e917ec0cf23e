"""Writing a new session frame by frame, committed atomically."""

from __future__ import annotations

import os
import uuid
from collections.abc import Sequence
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError, OutputExistsError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import remove_leftovers, remove_local_tree
from mmcsplat.storage.locking import WriterLock, session_lock
from mmcsplat.storage.transaction import Transaction

from .format import (
    FIELDS,
    FORMAT_VERSION,
    PLATE,
    RGB_DTYPE,
    check_camera_name,
    check_frame_index,
    checked_array,
    coverage_error,
    create_image_array,
    foreign_entries,
    frame_digest,
    is_session_store,
    local_path,
    open_group,
    provenance_record,
    recording_fingerprint,
    remove_remote,
)


class SessionWriter(Transaction):
    """Writes a new session frame by frame; nothing reads as a complete session before :meth:`commit`.

    Use as a context manager: an exception in the ``with`` block aborts (removes everything written), a
    normal exit commits unless :meth:`commit` or :meth:`abort` was already called. Cameras must already be
    undistorted (zero distortion). Optional fields (mask, depth, labels) are created on first write and, if
    written for a camera at all, must be written for every frame written for that camera; a camera may have
    one clean plate (:meth:`write_plate`). ``storage_options`` go to fsspec for URLs (credentials, endpoints).
    """

    def __init__(
        self,
        url: str | os.PathLike,
        *,
        cameras: Sequence[Camera],
        num_frames: int,
        fps: float,
        frame_times: np.ndarray | None = None,
        heldout: Sequence[str] = (),
        source: str = "",
        provenance: dict | None = None,
        overwrite: bool = False,
        storage_options: dict | None = None,
    ) -> None:
        self.url = os.fspath(url)
        self._storage_options = storage_options
        names = [camera.name for camera in cameras]
        if not names:
            raise InputError(f"{self.url}: a session needs at least one camera")
        if len(set(names)) != len(names):
            raise InputError(f"{self.url}: duplicate camera names in {names}")
        for camera in cameras:
            check_camera_name(camera.name)
            if camera.is_distorted:
                raise InputError(f"{self.url}: camera {camera.name!r} has distortion; undistort frames before storing them")
        unknown = sorted(set(heldout) - set(names))
        if unknown:
            raise InputError(f"{self.url}: held-out cameras {unknown} are not among the cameras {names}")
        if int(num_frames) < 1:
            raise InputError(f"{self.url}: num_frames must be ≥ 1, got {num_frames}")
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"{self.url}: fps must be positive, got {fps}")
        self.num_frames = int(num_frames)
        times = np.arange(self.num_frames) / fps if frame_times is None else np.asarray(frame_times, dtype=np.float64)
        if times.shape != (self.num_frames,) or not np.all(np.isfinite(times)):
            raise InputError(f"{self.url}: frame_times must be {self.num_frames} finite seconds, got shape {times.shape}")

        self._cameras = {camera.name: camera for camera in cameras}
        self._overwrite = overwrite
        self._lock: WriterLock | None = None
        self._target = local_path(url)
        if self._target is not None:
            if self._target.exists() and not overwrite:
                raise OutputExistsError(f"{self.url} already exists (--overwrite replaces it)")
            if self._target.exists() and not is_session_store(self._target):
                raise OutputExistsError(f"{self.url} exists and is not an mmcsplat session: overwrite replaces only a session, never other files")
            self._refuse_foreign()
            self._lock = session_lock(self._target)
            try:  # what a killed writer of this session left
                remove_leftovers(self._target.parent, f".{self._target.name}.partial-")
                remove_leftovers(self._target.parent, f".{self._target.name}.replaced-")
                self._partial = self._target.parent / f".{self._target.name}.partial-{uuid.uuid4().hex[:8]}"
                self._group = open_group(self._partial, "w-", None)
            except BaseException:
                self._release()
                raise
        else:
            self._partial = None
            import zarr

            try:  # in place: "w" clears what was there, "w-" refuses it
                self._group = open_group(url, "w" if overwrite else "w-", storage_options)
            except (FileExistsError, zarr.errors.ContainsGroupError, zarr.errors.ContainsArrayError) as error:
                raise OutputExistsError(f"{self.url} already exists (--overwrite replaces it)") from error
        try:
            self._group.attrs.update(
                {
                    "mmcsplat_session": FORMAT_VERSION,
                    "complete": False,
                    "cameras": [camera.to_dict() for camera in cameras],
                    "num_frames": self.num_frames,
                    "fps": float(fps),
                    "frame_times": times.tolist(),
                    "heldout": list(heldout),
                    "source": source,
                    "provenance": provenance_record(provenance),
                }
            )
            self._rgb = {
                name: create_image_array(self._group, f"cameras/{name}/rgb", camera, self.num_frames, RGB_DTYPE, (3,))
                for name, camera in self._cameras.items()
            }
        except BaseException:
            self.abort()
            raise
        self._present = {name: np.zeros(self.num_frames, dtype=bool) for name in names}
        # camera -> the digest of each written rgb frame, for the recording's fingerprint
        self._digests: dict[str, list[str | None]] = {name: [None] * self.num_frames for name in names}
        # camera -> field -> (zarr array, [T] bool of the frames written)
        self._fields: dict[str, dict[str, tuple[Any, np.ndarray]]] = {name: {} for name in names}
        self._plates: list[str] = []

    def write_frame(
        self,
        camera: str,
        t: int,
        rgb: np.ndarray,
        *,
        mask: np.ndarray | None = None,
        depth: np.ndarray | None = None,
        labels: np.ndarray | None = None,
    ) -> None:
        """Store frame ``t`` of ``camera`` (writing it again replaces it)."""
        self._check_open()
        if camera not in self._cameras:
            raise InputError(f"{self.url}: unknown camera {camera!r}; the session has {list(self._cameras)}")
        t = check_frame_index(self.url, camera, t, self.num_frames)
        spec = self._cameras[camera]
        values = {"rgb": checked_array(self.url, spec, "rgb", t, rgb)}
        for field, value in (("mask", mask), ("depth", depth), ("labels", labels)):
            if value is not None:
                values[field] = checked_array(self.url, spec, field, t, value)
        rgb = values.pop("rgb")
        self._rgb[camera][t] = rgb
        self._digests[camera][t] = frame_digest(rgb)
        for field, value in values.items():
            fields = self._fields[camera]
            if field not in fields:
                created = create_image_array(self._group, f"cameras/{camera}/{field}", spec, self.num_frames, FIELDS[field])
                fields[field] = (created, np.zeros(self.num_frames, dtype=bool))
            target, written = fields[field]
            target[t] = value
            written[t] = True
        self._present[camera][t] = True

    def write_plate(self, camera: str, rgb: np.ndarray) -> None:
        """Store ``camera``'s clean plate: [H, W, 3] uint8, the empty scene in the stored image space."""
        self._check_open()
        if camera not in self._cameras:
            raise InputError(f"{self.url}: unknown camera {camera!r}; the session has {list(self._cameras)}")
        plate = checked_array(self.url, self._cameras[camera], "rgb", None, rgb)
        self._group.create_array(f"cameras/{camera}/{PLATE}", data=plate, overwrite=True, config={"write_empty_chunks": True})
        if camera not in self._plates:
            self._plates.append(camera)

    def commit(self) -> None:
        """Finish the session: it reads as complete from now on. On failure everything is removed."""
        self._check_open()
        try:
            if not any(present.any() for present in self._present.values()):
                raise InputError(f"{self.url}: no frame was written")
            problems = [
                coverage_error(self.url, camera, field, written, self._present[camera])
                for camera, fields in self._fields.items()
                for field, (_, written) in fields.items()
            ]
            problems = [problem for problem in problems if problem]
            if problems:
                raise InputError("\n".join(problems))
            for camera, present in self._present.items():
                self._group.create_array(f"cameras/{camera}/present", data=present, config={"write_empty_chunks": True})
            fields = {camera: {field: field for field in fields} for camera, fields in self._fields.items()}
            attributes = self._group.attrs.asdict()
            fingerprint = recording_fingerprint(attributes["cameras"], self.num_frames, attributes["frame_times"], self._digests)
            self._group.attrs.update({"fields": fields, "plates": self._plates, "fingerprint": fingerprint, "complete": True})
            if self._partial is not None:
                self._move_into_place()
        except BaseException:
            self.abort()
            raise
        self._done = True
        self._release()

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()

    def _refuse_foreign(self) -> None:
        """Refuse to replace a session holding what mmcsplat did not write there (a run fitted into it)."""
        foreign = foreign_entries(self._target)
        if foreign:
            shown = ", ".join(foreign[:5]) + (" …" if len(foreign) > 5 else "")
            raise OutputExistsError(f"{self.url}: the session holds {shown}, which the session's writer did not put there (a run fitted "
                                    "into it?): overwrite would delete it; move it out first, or ingest to a new OUT")

    def _move_into_place(self) -> None:
        target = self._target
        if target.exists() or target.is_symlink():
            if not self._overwrite or not is_session_store(target):
                raise OutputExistsError(f"{self.url} appeared while the session was written (overwrite replaces only a session)")
            self._refuse_foreign()
            replaced = target.parent / f".{target.name}.replaced-{uuid.uuid4().hex[:8]}"
            os.replace(target, replaced)
            os.replace(self._partial, target)
            remove_local_tree(replaced)
        else:
            os.replace(self._partial, target)

    def abort(self) -> None:
        """Remove everything written; the writer cannot be used afterwards."""
        if self._done:
            return
        self._done = True
        try:
            if self._partial is not None:
                remove_local_tree(self._partial)
            else:
                remove_remote(self.url, self._storage_options)
        finally:
            self._release()


# ------------------------------------------------------------------------------------------------ reader
