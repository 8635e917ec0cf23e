"""The session store: one capture, undistorted, as a zarr v3 group at any URL zarr and fsspec accept.

:mod:`.format` owns the on-disk layout and its version; :mod:`.cache` the byte-bounded frame cache;
:mod:`.writer`, :mod:`.reader` and :mod:`.updater` write a new session, read one lazily, and replace its
fields atomically.
"""

from .cache import DEFAULT_CACHE_BYTES, FrameCache
from .format import (
    FIELDS,
    FORMAT_VERSION,
    PLATE,
    SOURCE_MASK,
    AbsentFrameError,
    IncompleteSessionError,
    SessionFrame,
    enclosing_session,
)
from .reader import SessionReader
from .updater import SessionUpdater
from .writer import SessionWriter

__all__ = [
    "DEFAULT_CACHE_BYTES",
    "FIELDS",
    "FORMAT_VERSION",
    "PLATE",
    "SOURCE_MASK",
    "AbsentFrameError",
    "FrameCache",
    "IncompleteSessionError",
    "SessionFrame",
    "SessionReader",
    "SessionUpdater",
    "SessionWriter",
    "enclosing_session",
]
