"""The session store: one capture, undistorted, as a zarr v3 group at any URL zarr and fsspec accept.

On-disk layout (format version 2; version 1 had no plates nor ``source_mask`` and still reads)::

    <session>/                         a zarr v3 group
        zarr.json                      group attributes:
            mmcsplat_session: 2          format version
            complete: true               written last; a session without it never reads
            cameras: [Camera.to_dict()]  the stored cameras, after undistortion (zero distortion), in order
            num_frames: T
            fps: float
            frame_times: [T] seconds
            heldout: [camera name]       cameras kept for evaluation
            source: str                  what the session was made from
            provenance: {mmcsplat, zarr, created (UTC, ISO 8601), command, ...}
            fields: {camera: {field: array name}}   where each optional field of a camera lives, and
                                                     source_mask: the replaced masks it was written with
            plates: [camera name]        the cameras with a clean plate
        cameras/<camera>/              one sub-group per camera (images may differ in size between cameras)
            present  [T] bool              which frames exist (D-NeRF is monocular: one camera per frame)
            rgb      [T, H, W, 3] uint8
            mask     [T, H, W] bool        optional: the subject's mask
            labels   [T, H, W] uint16      optional: semantic labels
            depth    [T, H, W] float16     optional: metres along the optical axis, 0 where no surface
            plate    [H, W, 3] uint8       optional: the empty scene as this camera sees it (a clean plate),
                                           which a fit may composite its subject over

Every image array has one frame per chunk (chunk file ``c.<t>.0.0[.0]``), compressed with zstd level 1
(it decodes at ~0.9 GB/s here, as fast as level 3, and encodes almost twice as fast). Chunks of absent
frames are never written: ``present`` is the truth about which frames exist, and a field covers every
present frame of its camera. After :class:`SessionUpdater` replaced a field, its array is named
``<field>.<token>``; ``fields`` says which. The masks a session was written with (at ingest: those the
capture shipped) are never deleted: the first replacement keeps their array as the field ``source_mask``,
which :meth:`SessionReader.source_mask` reads and :meth:`SessionReader.frame` leaves out.

Atomicity. A local session is written into a hidden sibling directory ``.<name>.partial-<token>`` and
renamed into place by :meth:`SessionWriter.commit`; an existing target is replaced only then. URLs that
cannot rename (``memory://``, object storage) are written in place and ``complete`` is set last:
:class:`SessionReader` refuses a session without it; there, ``overwrite=True`` clears an existing session
when the writer opens. :class:`SessionUpdater` writes new fields under fresh array names and swaps them in
with one write of the group attributes, so a reader opened at any moment sees each field either whole or
not at all.

Reading is lazy: :meth:`SessionReader.frame` decodes only the chunks of that (t, camera), through a
:class:`FrameCache` bounded in bytes, so memory does not grow with the length of the session.
"""

from __future__ import annotations

import datetime
import json
import os
import re
import shutil
import sys
import threading
import uuid
from abc import ABC, abstractmethod
from collections import OrderedDict
from collections.abc import Hashable, Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from .camera import Camera
from .memory import release_freed_memory

FORMAT_VERSION = 2
DEFAULT_CACHE_BYTES = 256 * 2**20
#: Bytes a cache stores between two returns of free memory to the system (one takes a few milliseconds).
TRIM_BYTES = 2 * 2**20
#: Optional per-frame fields, and the dtype each is stored as.
FIELDS = {"mask": np.dtype(bool), "labels": np.dtype(np.uint16), "depth": np.dtype(np.float16)}
#: Where ``fields`` keeps the array of the masks a session was written with once an update replaced them.
SOURCE_MASK = "source_mask"
#: A camera's clean plate: the array's name in its group.
PLATE = "plate"
_RGB = np.dtype(np.uint8)
_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


class IncompleteSessionError(ValueError):
    """A session whose write never committed (interrupted, or still in progress)."""


class AbsentFrameError(LookupError, ValueError):
    """A frame index within range that the session does not hold for that camera (a ValueError too, so
    the CLI reports it as a user error)."""


@attrs.frozen(eq=False)
class SessionFrame:
    """One decoded frame of one camera: ``rgb`` [H, W, 3] uint8, and where the session has them ``mask``
    [H, W] bool, ``depth`` [H, W] float32 metres, ``labels`` [H, W] uint16. Arrays are read-only: they may
    be shared through the cache."""

    rgb: np.ndarray
    mask: np.ndarray | None = None
    depth: np.ndarray | None = None
    labels: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        """The decoded size of all arrays."""
        return sum(a.nbytes for a in (self.rgb, self.mask, self.depth, self.labels) if a is not None)


class FrameCache:
    """A least-recently-used cache bounded by the total ``nbytes`` of its values, safe across threads.

    A value larger than the whole budget is never cached; ``hits``, ``misses`` and ``current_bytes`` say
    how it does. After every :data:`TRIM_BYTES` stored, the allocator's free pages go back to the system
    (:func:`mmcsplat.memory.release_freed_memory`): without that, a streamed training run's resident size
    grew to several times the budget.
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 0:
            raise ValueError(f"cache budget must be ≥ 0 bytes, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self.hits = 0
        self.misses = 0
        self.current_bytes = 0
        self._items: OrderedDict[Hashable, Any] = OrderedDict()
        self._lock = threading.Lock()
        self._stored_since_trim = 0

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._items

    def get(self, key: Hashable) -> Any | None:
        """The value under ``key`` (now the most recently used), or ``None``; counts a hit or a miss."""
        with self._lock:
            value = self._items.get(key)
            if value is None:
                self.misses += 1
                return None
            self._items.move_to_end(key)
            self.hits += 1
            return value

    def put(self, key: Hashable, value: Any) -> None:
        """Store ``value`` (anything with ``nbytes``), evicting the least recently used to stay in budget."""
        size = value.nbytes
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self.current_bytes -= old.nbytes
            if size > self.max_bytes:
                return
            while self.current_bytes + size > self.max_bytes:
                _, evicted = self._items.popitem(last=False)
                self.current_bytes -= evicted.nbytes
            self._items[key] = value
            self.current_bytes += size
            self._stored_since_trim += size
            trim = self._stored_since_trim >= TRIM_BYTES
            if trim:
                self._stored_since_trim = 0
        if trim:
            release_freed_memory()

    def clear(self) -> None:
        """Drop every value (the counters stay)."""
        with self._lock:
            self._items.clear()
            self.current_bytes = 0


# ----------------------------------------------------------------------------------------------- helpers


def _local_path(url: str | os.PathLike) -> Path | None:
    """The directory of a local session, or ``None`` for a URL that only fsspec can reach."""
    if isinstance(url, os.PathLike):
        return Path(url)
    if url.startswith("file://"):
        return Path(url.removeprefix("file://"))
    return None if _URL.match(url) else Path(url)


def _open_group(url: str | os.PathLike, mode: str, storage_options: dict | None):
    """Open the zarr group at ``url``; a missing one is a FileNotFoundError naming the URL."""
    import zarr

    local = _local_path(url)
    kwargs = {"storage_options": storage_options} if storage_options and local is None else {}
    try:
        return zarr.open_group(str(local) if local is not None else url, mode=mode, zarr_format=3, **kwargs)
    except (FileNotFoundError, zarr.errors.GroupNotFoundError) as error:
        raise FileNotFoundError(f"no session at {os.fspath(url)}") from error


def _remove_remote(url: str, storage_options: dict | None) -> None:
    """Delete everything under a URL that is not a local path."""
    import fsspec

    fs, path = fsspec.core.url_to_fs(url, **(storage_options or {}))
    if fs.exists(path):
        fs.rm(path, recursive=True)


def _remove_local(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _check_camera_name(name: str) -> None:
    """Camera names become zarr node names."""
    if not name or "/" in name or name.startswith("__") or not name.strip("."):
        raise ValueError(f"camera name {name!r} cannot name a zarr group (empty, '/', leading '__' or only dots)")


def _checked(session: str, camera: Camera, field: str, t: int | None, array: np.ndarray) -> np.ndarray:
    """``array`` (of frame ``t``, or the camera's plate for ``None``) in its stored dtype, after checking its
    shape and dtype against ``camera``."""
    storage = _RGB if field == "rgb" else FIELDS[field]
    shape = (camera.height, camera.width, 3) if field == "rgb" else (camera.height, camera.width)
    array = np.asarray(array)
    # Same kind of dtype (no bool as uint8, no float as int); only depth may lose precision (to float16).
    fits = array.dtype.kind == storage.kind and (field == "depth" or np.can_cast(array.dtype, storage, "safe"))
    if array.shape != shape or not fits:
        kinds = {"rgb": "uint8", "mask": "bool", "labels": "uint8 or uint16", "depth": "floating-point"}
        where = "plate" if t is None else f"frame {t}"
        raise ValueError(
            f"{session}: camera {camera.name!r} {where}: {field} must be {kinds[field]} {list(shape)}, "
            f"got {array.dtype} {list(array.shape)}"
        )
    return array.astype(storage, copy=False)


def _check_t(session: str, camera: str, t: int, num_frames: int) -> int:
    if not isinstance(t, int | np.integer) or isinstance(t, bool):
        raise TypeError(f"{session}: camera {camera!r}: frame index must be an integer, got {t!r}")
    if not 0 <= t < num_frames:
        raise IndexError(f"{session}: camera {camera!r}: frame {t} is out of range [0, {num_frames})")
    return int(t)


def _create_image_array(group, name: str, camera: Camera, num_frames: int, dtype: np.dtype, channels: tuple = ()):
    """A [T, H, W, ...] array with one compressed frame per chunk."""
    from zarr.codecs import ZstdCodec

    shape = (num_frames, camera.height, camera.width, *channels)
    return group.create_array(
        name,
        shape=shape,
        chunks=(1, *shape[1:]),
        dtype=dtype,
        compressors=[ZstdCodec(level=1)],
        chunk_key_encoding={"name": "default", "separator": "."},  # c.<t>.0.0[.0]: one file per frame, no subfolders
        # Only written frames have chunks anyway; zarr's test for chunks equal to the fill value would cost
        # more than compressing them (~0.2 s per 2048×1536 frame).
        config={"write_empty_chunks": True},
    )


def _coverage_error(session: str, camera: str, field: str, written: np.ndarray, present: np.ndarray) -> str | None:
    """Why ``field`` of ``camera`` does not cover exactly its present frames, or ``None``."""
    missing = np.flatnonzero(present & ~written)
    if not len(missing):
        return None
    shown = ", ".join(map(str, missing[:10])) + (" …" if len(missing) > 10 else "")
    return f"{session}: camera {camera!r}: {field} is missing for {len(missing)} present frame(s): {shown}"


def _provenance(extra: Mapping[str, Any] | None) -> dict[str, Any]:
    import zarr

    from . import __version__

    created = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    base = {"mmcsplat": __version__, "zarr": zarr.__version__, "created": created, "command": " ".join(sys.argv)}
    merged = base | dict(extra or {})
    try:
        json.dumps(merged)
    except TypeError as error:
        raise ValueError(f"session provenance must be JSON-serialisable: {error}") from error
    return merged


# ------------------------------------------------------------------------------------------------ writer


class _Transaction(ABC):
    """A context manager that commits on a normal exit and aborts on an exception, once."""

    url: str
    _done = False

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback) -> None:
        if self._done:
            return
        if kind is None:
            self.commit()
        else:
            self.abort()

    def _check_open(self) -> None:
        if self._done:
            raise RuntimeError(f"{self.url}: the {type(self).__name__} is already committed or aborted")

    @abstractmethod
    def commit(self) -> None:
        """Make the work visible, atomically."""

    @abstractmethod
    def abort(self) -> None:
        """Undo the work; a no-op once committed or aborted."""


class SessionWriter(_Transaction):
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
            raise ValueError(f"{self.url}: a session needs at least one camera")
        if len(set(names)) != len(names):
            raise ValueError(f"{self.url}: duplicate camera names in {names}")
        for camera in cameras:
            _check_camera_name(camera.name)
            if camera.is_distorted:
                raise ValueError(f"{self.url}: camera {camera.name!r} has distortion; undistort frames before storing them")
        unknown = sorted(set(heldout) - set(names))
        if unknown:
            raise ValueError(f"{self.url}: held-out cameras {unknown} are not among the cameras {names}")
        if int(num_frames) < 1:
            raise ValueError(f"{self.url}: num_frames must be ≥ 1, got {num_frames}")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"{self.url}: fps must be positive, got {fps}")
        self.num_frames = int(num_frames)
        times = np.arange(self.num_frames) / fps if frame_times is None else np.asarray(frame_times, dtype=np.float64)
        if times.shape != (self.num_frames,) or not np.all(np.isfinite(times)):
            raise ValueError(f"{self.url}: frame_times must be {self.num_frames} finite seconds, got shape {times.shape}")

        self._cameras = {camera.name: camera for camera in cameras}
        self._overwrite = overwrite
        self._target = _local_path(url)
        if self._target is not None:
            if self._target.exists() and not overwrite:
                raise FileExistsError(f"{self.url} already exists (overwrite it explicitly)")
            self._target.parent.mkdir(parents=True, exist_ok=True)
            self._partial = self._target.parent / f".{self._target.name}.partial-{uuid.uuid4().hex[:8]}"
            self._group = _open_group(self._partial, "w-", None)
        else:
            self._partial = None
            import zarr

            try:  # in place: "w" clears what was there, "w-" refuses it
                self._group = _open_group(url, "w" if overwrite else "w-", storage_options)
            except (FileExistsError, zarr.errors.ContainsGroupError, zarr.errors.ContainsArrayError) as error:
                raise FileExistsError(f"{self.url} already exists (overwrite it explicitly)") from error
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
                    "provenance": _provenance(provenance),
                }
            )
            self._rgb = {
                name: _create_image_array(self._group, f"cameras/{name}/rgb", camera, self.num_frames, _RGB, (3,))
                for name, camera in self._cameras.items()
            }
        except BaseException:
            self.abort()
            raise
        self._present = {name: np.zeros(self.num_frames, dtype=bool) for name in names}
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
            raise ValueError(f"{self.url}: unknown camera {camera!r}; the session has {list(self._cameras)}")
        t = _check_t(self.url, camera, t, self.num_frames)
        spec = self._cameras[camera]
        values = {"rgb": _checked(self.url, spec, "rgb", t, rgb)}
        for field, value in (("mask", mask), ("depth", depth), ("labels", labels)):
            if value is not None:
                values[field] = _checked(self.url, spec, field, t, value)
        self._rgb[camera][t] = values.pop("rgb")
        for field, value in values.items():
            fields = self._fields[camera]
            if field not in fields:
                created = _create_image_array(self._group, f"cameras/{camera}/{field}", spec, self.num_frames, FIELDS[field])
                fields[field] = (created, np.zeros(self.num_frames, dtype=bool))
            target, written = fields[field]
            target[t] = value
            written[t] = True
        self._present[camera][t] = True

    def write_plate(self, camera: str, rgb: np.ndarray) -> None:
        """Store ``camera``'s clean plate: [H, W, 3] uint8, the empty scene in the stored image space."""
        self._check_open()
        if camera not in self._cameras:
            raise ValueError(f"{self.url}: unknown camera {camera!r}; the session has {list(self._cameras)}")
        plate = _checked(self.url, self._cameras[camera], "rgb", None, rgb)
        self._group.create_array(f"cameras/{camera}/{PLATE}", data=plate, overwrite=True)
        if camera not in self._plates:
            self._plates.append(camera)

    def commit(self) -> None:
        """Finish the session: it reads as complete from now on. On failure everything is removed."""
        self._check_open()
        try:
            if not any(present.any() for present in self._present.values()):
                raise ValueError(f"{self.url}: no frame was written")
            problems = [
                _coverage_error(self.url, camera, field, written, self._present[camera])
                for camera, fields in self._fields.items()
                for field, (_, written) in fields.items()
            ]
            problems = [problem for problem in problems if problem]
            if problems:
                raise ValueError("\n".join(problems))
            for camera, present in self._present.items():
                self._group.create_array(f"cameras/{camera}/present", data=present)
            fields = {camera: {field: field for field in fields} for camera, fields in self._fields.items()}
            self._group.attrs.update({"fields": fields, "plates": self._plates, "complete": True})
            if self._partial is not None:
                self._move_into_place()
        except BaseException:
            self.abort()
            raise
        self._done = True

    def _move_into_place(self) -> None:
        target = self._target
        if target.exists() or target.is_symlink():
            if not self._overwrite:
                raise FileExistsError(f"{self.url} appeared while the session was written (overwrite it explicitly)")
            replaced = target.parent / f".{target.name}.replaced-{uuid.uuid4().hex[:8]}"
            os.replace(target, replaced)
            os.replace(self._partial, target)
            _remove_local(replaced)
        else:
            os.replace(self._partial, target)

    def abort(self) -> None:
        """Remove everything written; the writer cannot be used afterwards."""
        if self._done:
            return
        self._done = True
        if self._partial is not None:
            _remove_local(self._partial)
        else:
            _remove_remote(self.url, self._storage_options)


# ------------------------------------------------------------------------------------------------ reader


class _Session:
    """The metadata of a complete session, shared by the reader and the updater."""

    def __init__(self, url: str | os.PathLike, mode: str, storage_options: dict | None) -> None:
        self.url = os.fspath(url)
        self._group = _open_group(url, mode, storage_options)
        attributes = self._group.attrs.asdict()
        version = attributes.get("mmcsplat_session")
        if version is None:
            raise ValueError(f"{self.url} is a zarr group but not an mmcsplat session")
        if version > FORMAT_VERSION:
            raise ValueError(f"{self.url}: session format {version} is newer than this mmcsplat reads ({FORMAT_VERSION})")
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

    def camera(self, name: str) -> Camera:
        """The stored (undistorted) camera called ``name``."""
        try:
            return self._by_name[name]
        except KeyError:
            raise ValueError(f"{self.url}: unknown camera {name!r}; the session has {list(self.camera_names)}") from None

    def present(self, camera: str) -> np.ndarray:
        """[T] bool (read-only): which frames exist for ``camera``."""
        self.camera(camera)
        if camera not in self._present:
            present = np.asarray(self._group[f"cameras/{camera}/present"][:], dtype=bool)
            present.setflags(write=False)
            self._present[camera] = present
        return self._present[camera]

    def has(self, field: str, camera: str | None = None) -> bool:
        """Whether ``camera`` (with ``None``: any camera) has ``field``, one of mask, depth, labels."""
        if field not in FIELDS:
            raise ValueError(f"unknown session field {field!r}; fields are {list(FIELDS)}")
        cameras = self.camera_names if camera is None else (self.camera(camera).name,)
        return any(field in self._field_names.get(name, {}) for name in cameras)

    def _source_mask_array(self, camera: str) -> str | None:
        """The name of the array holding the masks ``camera`` was written with, or ``None``."""
        names = self._field_names.get(camera, {})
        if SOURCE_MASK in names:
            return names[SOURCE_MASK]
        return "mask" if names.get("mask") == "mask" else None  # the writer names arrays after their field

    def _check_frame(self, t: int, camera: str) -> int:
        self.camera(camera)
        t = _check_t(self.url, camera, t, self.num_frames)
        if not self.present(camera)[t]:
            raise AbsentFrameError(f"{self.url}: frame {t} of camera {camera!r} is not in the session")
        return t


class SessionReader(_Session):
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

    def __repr__(self) -> str:
        return f"SessionReader({self.url!r}: {len(self.cameras)} cameras, {self.num_frames} frames)"

    def _array(self, camera: str, name: str):
        """The zarr array ``name`` of ``camera`` (opened once)."""
        key = (camera, name)
        if key not in self._arrays:
            self._arrays[key] = self._group[f"cameras/{camera}/{name}"]
        return self._arrays[key]

    def frame(self, t: int, camera: str) -> SessionFrame:
        """Frame ``t`` of ``camera``. Errors: unknown camera (ValueError), ``t`` out of range (IndexError),
        a frame the session lacks (:class:`AbsentFrameError`)."""
        t = self._check_frame(t, camera)
        cached = self.cache.get((camera, t))
        if cached is not None:
            return cached
        arrays = {"rgb": self._array(camera, "rgb")[t]}
        for field, name in self._field_names[camera].items():
            if field in FIELDS:  # not source_mask
                arrays[field] = self._array(camera, name)[t]
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
        plate = self._group[f"cameras/{camera}/{PLATE}"][...]
        plate.setflags(write=False)
        return plate

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
            raise ValueError(f"{self.url}: camera {camera!r} has no masks from its capture")
        mask = self._array(camera, name)[t]
        mask.setflags(write=False)
        return mask


# ----------------------------------------------------------------------------------------------- updater


class SessionUpdater(_Session, _Transaction):
    """Adds or replaces whole mask/labels/depth fields of a complete session, atomically.

    New fields are written under fresh array names (``<field>.<token>``) that no reader looks at; one
    write of the group attributes in :meth:`commit` swaps them all in, then the replaced arrays are
    deleted — except the masks the session was written with, which the first replacement keeps as the
    field :data:`SOURCE_MASK` (the ``precomputed`` segmenter starts from them). A field written for a
    camera must cover every present frame of it. A context manager like :class:`SessionWriter`. An updater
    killed before commit leaves only unreferenced arrays behind. One updater at a time: two committing
    concurrently would each keep only its own fields.
    """

    def __init__(self, url: str | os.PathLike, *, storage_options: dict | None = None) -> None:
        super().__init__(url, "r+", storage_options)
        self._token = uuid.uuid4().hex[:8]
        self._new: dict[tuple[str, str], tuple[Any, np.ndarray]] = {}  # (camera, field) -> (array, written)

    def write(self, camera: str, field: str, t: int, array: np.ndarray) -> None:
        """Set ``field`` (mask, labels or depth) of frame ``t`` of ``camera``."""
        self._check_open()
        if field not in FIELDS:
            raise ValueError(f"unknown session field {field!r}; fields are {list(FIELDS)}")
        t = self._check_frame(t, camera)
        value = _checked(self.url, self.camera(camera), field, t, array)
        if (camera, field) not in self._new:
            name = f"cameras/{camera}/{field}.{self._token}"
            created = _create_image_array(self._group, name, self.camera(camera), self.num_frames, FIELDS[field])
            self._new[camera, field] = (created, np.zeros(self.num_frames, dtype=bool))
        target, written = self._new[camera, field]
        target[t] = value
        written[t] = True

    def commit(self) -> None:
        """Swap every written field in at once. On failure the session is left as it was."""
        self._check_open()
        problems = [
            _coverage_error(self.url, camera, field, written, self.present(camera))
            for (camera, field), (_, written) in self._new.items()
        ]
        problems = [problem for problem in problems if problem]
        if problems:
            self.abort()
            raise ValueError("\n".join(problems))
        fields = {camera: dict(names) for camera, names in self._field_names.items()}
        replaced = []
        for camera, field in self._new:
            names = fields.setdefault(camera, {})
            if names.get(field) == field == "mask":  # the masks the session was written with: kept
                names[SOURCE_MASK] = field
            elif field in names:
                replaced.append(f"cameras/{camera}/{names[field]}")
            names[field] = f"{field}.{self._token}"
        self._group.attrs.update({"fields": fields})
        self._field_names = fields
        self._done = True
        for path in replaced:
            del self._group[path]

    def abort(self) -> None:
        """Delete the arrays written so far; the session is left as it was."""
        if self._done:
            return
        self._done = True
        for camera, field in self._new:
            del self._group[f"cameras/{camera}/{field}.{self._token}"]
