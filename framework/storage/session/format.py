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
            fingerprint: str             the recording's identity (:func:`recording_fingerprint`), written
                                         at commit; absent in sessions written before it existed (unknown)
            fields: {camera: {field: array name}}   where each optional field of a camera lives, and
                                                     source_mask: the replaced masks it was written with
            plates: [camera name]        the cameras with a clean plate
            plate_arrays: {camera: name} where a plate replaced by SessionUpdater lives (default ``plate``)
            plate_sources: {camera: {...}} how each plate was made: {"kind": "recorded"} (the default) or
                                         {"kind": "estimated", ...} with the estimate's quality (pipeline.plates)
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
:class:`FrameCache` bounded in bytes, so memory does not grow with the length of the session."""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.scene.camera import Camera

FORMAT_VERSION = 2
#: Optional per-frame fields, and the dtype each is stored as.
FIELDS = {"mask": np.dtype(bool), "labels": np.dtype(np.uint16), "depth": np.dtype(np.float16)}
#: Where ``fields`` keeps the array of the masks a session was written with once an update replaced them.
SOURCE_MASK = "source_mask"
#: A camera's clean plate: the array's name in its group.
PLATE = "plate"
RGB_DTYPE = np.dtype(np.uint8)
URL_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


class IncompleteSessionError(InputError):
    """A session whose write never committed (interrupted, or still in progress)."""


class AbsentFrameError(InputError, LookupError):
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


def local_path(url: str | os.PathLike) -> Path | None:
    """The directory of a local session, or ``None`` for a URL that only fsspec can reach."""
    if isinstance(url, os.PathLike):
        return Path(url)
    if url.startswith("file://"):
        return Path(url.removeprefix("file://"))
    return None if URL_SCHEME.match(url) else Path(url)


def is_session_store(path: Path) -> bool:
    """Whether the local folder ``path`` is an mmcsplat session (its zarr.json names the format), the
    only kind of folder ``overwrite`` may replace."""
    try:
        metadata = json.loads((Path(path) / "zarr.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(metadata, dict) and "mmcsplat_session" in (metadata.get("attributes") or {})


#: What a local session folder holds; anything else in it was put there by someone else.
SESSION_ENTRIES = frozenset({"zarr.json", "cameras"})


def foreign_entries(path: Path) -> list[str]:
    """The names in the session folder ``path`` that are not the session's own (a run fitted into it, the
    user's files): ``overwrite`` must not delete them."""
    return sorted(entry.name for entry in Path(path).iterdir() if entry.name not in SESSION_ENTRIES) if Path(path).is_dir() else []


def enclosing_session(path: str | os.PathLike) -> Path | None:
    """The local session store that ``path`` is, or lies inside, or ``None``: no output goes there."""
    path = Path(os.path.abspath(path))
    return next((folder for folder in (path, *path.parents) if is_session_store(folder)), None)


def open_group(url: str | os.PathLike, mode: str, storage_options: dict | None):
    """Open the zarr group at ``url``; a missing one is a FileNotFoundError naming the URL."""
    import zarr

    local = local_path(url)
    kwargs = {"storage_options": storage_options} if storage_options and local is None else {}
    try:
        return zarr.open_group(str(local) if local is not None else url, mode=mode, zarr_format=3, **kwargs)
    except (FileNotFoundError, zarr.errors.GroupNotFoundError) as error:
        raise MissingFileError(f"no session at {os.fspath(url)}") from error
    except ValueError as error:  # a garbled zarr.json (json.JSONDecodeError) or metadata zarr cannot parse
        if local is None:
            raise InputError(f"{os.fspath(url)}: cannot be opened as a session store ({error})") from error
        raise InputError(f"{os.fspath(url)}: the store's metadata (zarr.json) is garbled ({error}); the store is damaged") from error
    except NotADirectoryError as error:
        raise InputError(f"{os.fspath(url)}: a file lies where the session's folder would be ({error})") from error
    except FileExistsError:  # mode 'w-' on existing data: the writer says what to do
        raise
    except (ImportError, NotImplementedError, OSError) as error:  # fsspec: its package missing, a bad URL
        if local is not None:
            raise
        raise InputError(f"{os.fspath(url)}: cannot be opened as a session store ({error})") from error


def remove_remote(url: str, storage_options: dict | None) -> None:
    """Delete everything under a URL that is not a local path."""
    import fsspec

    fs, path = fsspec.core.url_to_fs(url, **(storage_options or {}))
    if fs.exists(path):
        fs.rm(path, recursive=True)


def check_camera_name(name: str) -> None:
    """Camera names become zarr node names."""
    if not name or "/" in name or name.startswith("__") or not name.strip("."):
        raise InputError(f"camera name {name!r} cannot name a zarr group (empty, '/', leading '__' or only dots)")


def checked_array(session: str, camera: Camera, field: str, t: int | None, array: np.ndarray) -> np.ndarray:
    """``array`` (of frame ``t``, or the camera's plate for ``None``) in its stored dtype, after checking its
    shape and dtype against ``camera``."""
    storage = RGB_DTYPE if field == "rgb" else FIELDS[field]
    shape = (camera.height, camera.width, 3) if field == "rgb" else (camera.height, camera.width)
    array = np.asarray(array)
    # Same kind of dtype (no bool as uint8, no float as int); only depth may lose precision (to float16).
    fits = array.dtype.kind == storage.kind and (field == "depth" or np.can_cast(array.dtype, storage, "safe"))
    if array.shape != shape or not fits:
        kinds = {"rgb": "uint8", "mask": "bool", "labels": "uint8 or uint16", "depth": "floating-point"}
        where = "plate" if t is None else f"frame {t}"
        raise InputError(
            f"{session}: camera {camera.name!r} {where}: {field} must be {kinds[field]} {list(shape)}, "
            f"got {array.dtype} {list(array.shape)}"
        )
    return array.astype(storage, copy=False)


def check_frame_index(session: str, camera: str, t: int, num_frames: int) -> int:
    if not isinstance(t, int | np.integer) or isinstance(t, bool):
        raise TypeError(f"{session}: camera {camera!r}: frame index must be an integer, got {t!r}")
    if not 0 <= t < num_frames:
        raise IndexError(f"{session}: camera {camera!r}: frame {t} is out of range [0, {num_frames})")
    return int(t)


def create_image_array(group, name: str, camera: Camera, num_frames: int, dtype: np.dtype, channels: tuple = ()):
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


def coverage_error(session: str, camera: str, field: str, written: np.ndarray, present: np.ndarray) -> str | None:
    """Why ``field`` of ``camera`` does not cover exactly its present frames, or ``None``."""
    missing = np.flatnonzero(present & ~written)
    if not len(missing):
        return None
    shown = ", ".join(map(str, missing[:10])) + (" …" if len(missing) > 10 else "")
    return f"{session}: camera {camera!r}: {field} is missing for {len(missing)} present frame(s): {shown}"


def frame_digest(rgb: np.ndarray) -> str:
    """The digest of one stored rgb frame (one chunk of the session), for :func:`recording_fingerprint`."""
    return hashlib.blake2b(np.ascontiguousarray(rgb).data, digest_size=16).hexdigest()


def recording_fingerprint(cameras: list[dict], num_frames: int, frame_times: list[float], digests: Mapping[str, list[str | None]]) -> str:
    """The identity of a recording: a digest over its cameras (calibration and image sizes), frame count,
    frame times and the digest of every stored rgb frame (``None`` for an absent one). Masks, plates and
    provenance are left out: segmenting a session again does not make it another recording."""
    record = {"cameras": cameras, "num_frames": num_frames, "frame_times": frame_times, "frames": {name: list(digests[name]) for name in sorted(digests)}}
    return hashlib.blake2b(json.dumps(record, sort_keys=True).encode(), digest_size=16).hexdigest()


def provenance_record(extra: Mapping[str, Any] | None) -> dict[str, Any]:
    import zarr

    from mmcsplat import __version__

    created = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    base = {"mmcsplat": __version__, "zarr": zarr.__version__, "created": created, "command": " ".join(sys.argv)}
    merged = base | dict(extra or {})
    try:
        json.dumps(merged)
    except TypeError as error:
        raise InputError(f"session provenance must be JSON-serialisable: {error}") from error
    return merged
