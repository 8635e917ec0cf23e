"""Replacing fields of a session (masks, labels, plates) atomically, as segmenters do, and keeping only some of
its cameras (recalibrated or not), as a study's modified sessions do."""

from __future__ import annotations

import os
import uuid
from collections.abc import Sequence
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.locking import session_lock
from mmcsplat.storage.transaction import Transaction

from .format import (
    FIELDS,
    PLATE,
    SOURCE_MASK,
    checked_array,
    coverage_error,
    create_image_array,
    local_path,
)
from .reader import SessionBase


class SessionUpdater(SessionBase, Transaction):
    """Adds or replaces whole mask/labels/depth fields of a complete session, atomically.

    New fields are written under fresh array names (``<field>.<token>``) that no reader looks at; one
    write of the group attributes in :meth:`commit` swaps them all in, then the replaced arrays are
    deleted — except the masks the session was written with, which the first replacement keeps as the
    field :data:`SOURCE_MASK` (the ``precomputed`` segmenter starts from them). A field written for a
    camera must cover every present frame of it. A context manager like :class:`SessionWriter`. An updater
    killed before commit leaves only unreferenced arrays behind, which the next updater deletes. One updater
    at a time: a second one of a local session while the first is open is refused (a writer lock).
    """

    def __init__(self, url: str | os.PathLike, *, storage_options: dict | None = None) -> None:
        target = local_path(url)
        self._lock = session_lock(target) if target is not None else None
        try:
            super().__init__(url, "r+", storage_options)
            self._remove_orphans()
        except BaseException:
            self._release()
            raise
        self._token = uuid.uuid4().hex[:8]
        self._new: dict[tuple[str, str], tuple[Any, np.ndarray]] = {}  # (camera, field) -> (array, written)
        self._new_plates: dict[str, dict[str, Any]] = {}  # camera -> its plate's source record
        self._kept: tuple[Camera, ...] | None = None  # the cameras left after the commit (None: all, unchanged)

    def _remove_orphans(self) -> None:
        """Delete the ``<field>.<token>`` arrays of updaters killed before their commit (no field names them)."""
        plates = self._attributes.get("plate_arrays", {})
        for camera in self.camera_names:
            referenced = {*self._field_names.get(camera, {}).values(), plates.get(camera, PLATE)}
            group = self._group[f"cameras/{camera}"]
            for name in list(group.array_keys()):
                field, dot, token = name.partition(".")
                if dot and (field in FIELDS or field == PLATE) and name not in referenced:
                    del group[name]

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()

    def write(self, camera: str, field: str, t: int, array: np.ndarray) -> None:
        """Set ``field`` (mask, labels or depth) of frame ``t`` of ``camera``."""
        self._check_open()
        if field not in FIELDS:
            raise InputError(f"unknown session field {field!r}; fields are {list(FIELDS)}")
        t = self._check_frame(t, camera)
        value = checked_array(self.url, self.camera(camera), field, t, array)
        if (camera, field) not in self._new:
            name = f"cameras/{camera}/{field}.{self._token}"
            created = create_image_array(self._group, name, self.camera(camera), self.num_frames, FIELDS[field])
            self._new[camera, field] = (created, np.zeros(self.num_frames, dtype=bool))
        target, written = self._new[camera, field]
        target[t] = value
        written[t] = True

    def pending(self, camera: str, field: str) -> Any:
        """The array of ``field`` being written for ``camera`` (readable before the commit)."""
        self._check_open()
        if (camera, field) not in self._new:
            raise InputError(f"{self.url}: no {field} of camera {camera!r} has been written in this update")
        return self._new[camera, field][0]

    def write_plate(self, camera: str, rgb: np.ndarray, source: dict[str, Any]) -> None:
        """Set ``camera``'s clean plate ([H, W, 3] uint8) and the record of how it was made (``source``,
        e.g. ``{"kind": "estimated", ...}``), replacing any plate it had."""
        self._check_open()
        plate = checked_array(self.url, self.camera(camera), "rgb", None, rgb)
        self._group.create_array(f"cameras/{camera}/{PLATE}.{self._token}", data=plate, config={"write_empty_chunks": True})
        self._new_plates[camera] = dict(source)

    def keep_cameras(self, cameras: Sequence[Camera]) -> None:
        """Keep only ``cameras`` — the session's, by name, in this order; one with another calibration (a
        perturbed pose) replaces the stored one — from the commit on; every array of the others is deleted then."""
        self._check_open()
        unknown = [camera.name for camera in cameras if camera.name not in self.camera_names]
        if unknown:
            raise InputError(f"{self.url}: no camera {unknown[0]!r} to keep; the session has {list(self.camera_names)}")
        self._kept = tuple(cameras)

    def commit(self) -> None:
        """Swap every written field and plate in at once. On failure the session is left as it was."""
        self._check_open()
        problems = [
            coverage_error(self.url, camera, field, written, self.present(camera))
            for (camera, field), (_, written) in self._new.items()
        ]
        problems = [problem for problem in problems if problem]
        if problems:
            self.abort()
            raise InputError("\n".join(problems))
        fields = {camera: dict(names) for camera, names in self._field_names.items()}
        replaced = []
        for camera, field in self._new:
            names = fields.setdefault(camera, {})
            if names.get(field) == field == "mask":  # the masks the session was written with: kept
                names[SOURCE_MASK] = field
            elif field in names:
                replaced.append(f"cameras/{camera}/{names[field]}")
            names[field] = f"{field}.{self._token}"
        plate_arrays = dict(self._attributes.get("plate_arrays", {}))
        plate_sources = dict(self._attributes.get("plate_sources", {}))
        for camera, source in self._new_plates.items():
            if camera in self._plates:
                replaced.append(f"cameras/{camera}/{plate_arrays.get(camera, PLATE)}")
            plate_arrays[camera], plate_sources[camera] = f"{PLATE}.{self._token}", source
        plates = sorted({*self._plates, *self._new_plates}, key=self.camera_names.index)
        update: dict[str, Any] = {"fields": fields, "plates": plates, "plate_arrays": plate_arrays, "plate_sources": plate_sources}
        if self._kept is not None:
            kept = [camera.name for camera in self._kept]
            replaced += [f"cameras/{name}" for name in self.camera_names if name not in kept]  # after their own arrays
            update = {
                "cameras": [camera.to_dict() for camera in self._kept],
                "heldout": [name for name in self._attributes["heldout"] if name in kept],
                "fields": {name: names for name, names in fields.items() if name in kept},
                "plates": [name for name in plates if name in kept],
                "plate_arrays": {name: array for name, array in plate_arrays.items() if name in kept},
                "plate_sources": {name: source for name, source in plate_sources.items() if name in kept},
            }
        self._group.attrs.update(update)
        self._field_names = update["fields"]
        self._done = True
        try:
            for path in replaced:
                del self._group[path]
        finally:
            self._release()

    def abort(self) -> None:
        """Delete the arrays written so far; the session is left as it was."""
        if self._done:
            return
        self._done = True
        try:
            for camera, field in self._new:
                del self._group[f"cameras/{camera}/{field}.{self._token}"]
            for camera in self._new_plates:
                del self._group[f"cameras/{camera}/{PLATE}.{self._token}"]
        finally:
            self._release()
