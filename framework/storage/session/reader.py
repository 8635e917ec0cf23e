"""Reading a session lazily: frames decoded on demand through the byte-bounded cache."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.chunks import open_stored, read_stored

from .cache import DEFAULT_CACHE_BYTES, FrameCache
from .format import (
    FIELDS,
    FORMAT_VERSION,
    PLATE,
    SOURCE_MASK,
    AbsentFrameError,
    IncompleteSessionError,
    SessionFrame,
    check_frame_index,
    open_group,
)


class SessionBase:
    """The metadata of a complete session, shared by the reader and the updater."""

    def __init__(self, url: str | os.PathLike, mode: str, storage_options: dict | None) -> None:
        self.url = os.fspath(url)
        self._group = open_group(url, mode, storage_options)
        attributes = self._group.attrs.asdict()
        version = attributes.get("mmcsplat_session")
        if version is None:
            raise InputError(f"{self.url} is a zarr group but not an mmcsplat session")
        if version > FORMAT_VERSION:
            raise InputError(f"{self.url}: session format {version} is newer than this mmcsplat reads ({FORMAT_VERSION})")
        if attributes.get("complete") is not True:
            raise IncompleteSessionError(f"{self.url}: the session was never completed (its write was interrupted or is still going on)")
        self.cameras = tuple(Camera.from_dict(data) for data in attributes["cameras"])
        self.camera_names = tuple(camera.name for camera in self.cameras)
        self.num_frames = int(attributes["num_frames"])
        self._by_name = dict(zip(self.camera_names, self.cameras, strict=True))
        self._field_names: dict[str, dict[str, str]] = attributes["fields"]
        self._plates = frozenset(attributes.get("plates", ()))
        self._attributes = attributes
        self._present: dict[str, np.ndarray] = {}

    @property
    def fingerprint(self) -> str | None:
        """The recording's identity (:func:`~mmcsplat.storage.session.format.recording_fingerprint`), or
        ``None`` for a session written before mmcsplat recorded it (unknown)."""
        return self._attributes.get("fingerprint")

    def camera(self, name: str) -> Camera:
        """The stored (undistorted) camera called ``name``."""
        try:
            return self._by_name[name]
        except KeyError:
            raise InputError(f"{self.url}: unknown camera {name!r}; the session has {list(self.camera_names)}") from None

    def present(self, camera: str) -> np.ndarray:
        """[T] bool (read-only): which frames exist for ``camera``."""
        self.camera(camera)
        if camera not in self._present:
            where = f"session {self.url}: camera {camera!r} present"
            present = np.asarray(read_stored(open_stored(self._group, f"cameras/{camera}/present", where), None, where), dtype=bool)
            present.setflags(write=False)
            self._present[camera] = present
        return self._present[camera]

    def has(self, field: str, camera: str | None = None) -> bool:
        """Whether ``camera`` (with ``None``: any camera) has ``field``, one of mask, depth, labels."""
        if field not in FIELDS:
            raise InputError(f"unknown session field {field!r}; fields are {list(FIELDS)}")
        cameras = self.camera_names if camera is None else (self.camera(camera).name,)
        return any(field in self._field_names.get(name, {}) for name in cameras)

    def field_array(self, field: str, camera: str) -> str | None:
        """The name of the array holding ``camera``'s ``field`` (a segmenter's run writes a new one), or ``None``."""
        return self._field_names.get(self.camera(camera).name, {}).get(field)

    def _source_mask_array(self, camera: str) -> str | None:
        """The name of the array holding the masks ``camera`` was written with, or ``None``."""
        names = self._field_names.get(camera, {})
        if SOURCE_MASK in names:
            return names[SOURCE_MASK]
        return "mask" if names.get("mask") == "mask" else None  # the writer names arrays after their field

    def _check_frame(self, t: int, camera: str) -> int:
        self.camera(camera)
        t = check_frame_index(self.url, camera, t, self.num_frames)
        if not self.present(camera)[t]:
            raise AbsentFrameError(f"{self.url}: frame {t} of camera {camera!r} is not in the session")
        return t


class SessionReader(SessionBase):
    """A complete session, read lazily: :meth:`frame` decodes one (t, camera) on demand through a
    :class:`FrameCache` of ``cache_bytes``. Raises FileNotFoundError for nothing at ``url`` and
    :class:`IncompleteSessionError` for a session whose write never committed.

    A reader opened before a :class:`SessionUpdater` commit must be reopened to see the new fields.
    """

    def __init__(
        self, url: str | os.PathLike, *, cache_bytes: int = DEFAULT_CACHE_BYTES, storage_options: dict | None = None
    ) -> None:
        super().__init__(url, "r", storage_options)
        attributes = self._attributes
        self.heldout: tuple[str, ...] = tuple(attributes["heldout"])
        self.train_cameras = tuple(name for name in self.camera_names if name not in self.heldout)
        self.fps = float(attributes["fps"])
        self.frame_times = np.asarray(attributes["frame_times"], dtype=np.float64)
        self.frame_times.setflags(write=False)
        self.source: str = attributes["source"]
        self.provenance: dict[str, Any] = attributes["provenance"]
        self.cache = FrameCache(cache_bytes)
        self._arrays: dict[tuple[str, str], Any] = {}

    @property
    def capture_fps(self) -> float:
        """The source capture's frame rate: the session's times the ``--frames`` step ingest took."""
        return self.fps * self.capture_start_step[1]

    @property
    def capture_start_step(self) -> tuple[int, int]:
        """(the capture's frame number of session frame 0, capture frames per session frame): what ingest's
        ``--frames START:STOP:STEP`` took."""
        start, _, step = self.provenance.get("frames", [0, None, 1])
        return int(start or 0), int(step or 1)

    def capture_frames(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """The frame numbers in the source capture of session ``frames`` (ingest may have taken
        ``--frames START:STOP:STEP``)."""
        start, step = self.capture_start_step
        return start + np.asarray(frames, dtype=np.int64) * step

    def session_frames(self, capture: Sequence[int] | np.ndarray, what: str) -> np.ndarray:
        """The session frames of the capture frame numbers ``capture`` (the inverse of :meth:`capture_frames`);
        raises :class:`InputError` naming ``what`` (the file they came from) for one the session did not take."""
        start, step = self.capture_start_step
        offset = np.asarray(capture, dtype=np.int64) - start
        frames = offset // step
        outside = (offset % step != 0) | (frames < 0) | (frames >= self.num_frames)
        if outside.any():
            taken = self.capture_frames([0, self.num_frames - 1])
            raise InputError(f"{what}: capture frame {int(np.asarray(capture)[outside][0])} is not one of session {self.url}'s "
                             f"(it took frames {taken[0]}–{taken[1]}" + (f" every {step}" if step > 1 else "") + ")")
        return frames

    def source_frames(self, camera: str, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """The frame numbers in ``camera``'s own source — its video's frames, which 2D keypoints detected in it
        follow — of session ``frames``, −1 where the camera lacks the frame: the capture frame numbers
        (:meth:`capture_frames`) unless ingest recorded the camera's frames placed otherwise
        (``provenance.source_frame_offsets``: a Caliscope camera that missed a moment is a frame behind from there)."""
        capture = self.capture_frames(frames)
        runs = np.asarray(self.provenance.get("source_frame_offsets", {}).get(camera, []), dtype=np.int64).reshape(-1, 2)
        offsets = np.zeros_like(capture)
        if len(runs):
            run = np.searchsorted(runs[:, 0], capture, side="right") - 1
            offsets = np.where(run >= 0, runs[np.maximum(run, 0), 1], 0)
        return np.where(self.present(camera)[np.asarray(frames, dtype=np.int64)], capture + offsets, -1)

    def recorded_cameras(self) -> dict[str, Camera]:
        """The cameras as recorded (before undistortion and rescaling) by name, from the provenance; empty
        for a session ingested before mmcsplat kept them."""
        return {data["name"]: Camera.from_dict(data) for data in self.provenance.get("source_cameras", [])}

    def __repr__(self) -> str:
        return f"SessionReader({self.url!r}: {len(self.cameras)} cameras, {self.num_frames} frames)"

    def _array(self, camera: str, name: str):
        """The zarr array ``name`` of ``camera`` (opened once)."""
        key = (camera, name)
        if key not in self._arrays:
            self._arrays[key] = open_stored(self._group, f"cameras/{camera}/{name}", f"session {self.url}")
        return self._arrays[key]

    def _stored(self, camera: str, name: str, field: str, t: int) -> np.ndarray:
        """Frame ``t`` of the array ``name`` of ``camera``; a missing or corrupt chunk is an error naming it."""
        return read_stored(self._array(camera, name), t, f"session {self.url}: camera {camera!r} {field}, frame {t}")

    def frame(self, t: int, camera: str) -> SessionFrame:
        """Frame ``t`` of ``camera``. Errors: unknown camera (ValueError), ``t`` out of range (IndexError),
        a frame the session lacks (:class:`AbsentFrameError`)."""
        t = self._check_frame(t, camera)
        cached = self.cache.get((camera, t))
        if cached is not None:
            return cached
        arrays = {"rgb": self._stored(camera, "rgb", "rgb", t)}
        for field, name in self._field_names[camera].items():
            if field in FIELDS:  # not source_mask
                arrays[field] = self._stored(camera, name, field, t)
        if "depth" in arrays:
            arrays["depth"] = arrays["depth"].astype(np.float32)
        for array in arrays.values():
            array.setflags(write=False)
        frame = SessionFrame(**arrays)
        self.cache.put((camera, t), frame)
        return frame

    def plate(self, camera: str) -> np.ndarray | None:
        """[H, W, 3] uint8, read-only: ``camera``'s clean plate (the empty scene), or ``None`` without one."""
        self.camera(camera)
        if camera not in self._plates:
            return None
        name = self._attributes.get("plate_arrays", {}).get(camera, PLATE)
        plate = read_stored(open_stored(self._group, f"cameras/{camera}/{name}", f"session {self.url}"), None, f"session {self.url}: camera {camera!r} plate")
        plate.setflags(write=False)
        return plate

    def plate_source(self, camera: str) -> dict[str, Any] | None:
        """How ``camera``'s plate was made (``{"kind": "recorded"}`` or ``{"kind": "estimated", …}``), or
        ``None`` without a plate."""
        self.camera(camera)
        if camera not in self._plates:
            return None
        return dict(self._attributes.get("plate_sources", {}).get(camera, {"kind": "recorded"}))

    def has_source_mask(self, camera: str) -> bool:
        """Whether ``camera`` has masks from when the session was written (at ingest: the capture's own)."""
        self.camera(camera)
        return self._source_mask_array(camera) is not None

    def source_mask(self, t: int, camera: str) -> np.ndarray:
        """[H, W] bool, read-only: frame ``t``'s mask of ``camera`` as the session was written (at ingest:
        the capture's own), whatever segmenters stored since; not cached. Errors as :meth:`frame`, and a
        ValueError for a camera without such masks."""
        t = self._check_frame(t, camera)
        name = self._source_mask_array(camera)
        if name is None:
            raise InputError(f"{self.url}: camera {camera!r} has no masks from its capture")
        mask = self._stored(camera, name, "source mask", t)
        mask.setflags(write=False)
        return mask


# ----------------------------------------------------------------------------------------------- updater
