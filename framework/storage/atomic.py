"""Atomic file writes: a reader sees the old file or the new one, never half of one; and files written
together (a checkpoint and the record naming its iteration) are not split by Ctrl-C or SIGTERM."""

from __future__ import annotations

import errno
import glob
import json
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mmcsplat.plugin_api.errors import MissingFileError, MmcsplatError, OutputExistsError
from mmcsplat.storage.chunks import settle_zarr_io

#: The errors of a file system that has no room left (a full disk, an exhausted quota).
NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait until the block has run: each file is atomic on its own, but a stop between
    two of them would leave a checkpoint ahead of the record that says where it is. A signal that arrives
    meanwhile is noted and raised again, to the handler of before, when the block ends. A signal mask would
    not do: any of torch's or numba's threads may take the signal. Outside the main thread (which alone
    sets handlers) nothing is deferred."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {number: signal.signal(number, lambda received, _frame: pending.append(received)) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler if handler is not None else signal.SIG_DFL)  # None: set outside Python
        for number in pending:
            signal.raise_signal(number)


class DiskFullError(MmcsplatError, OSError):
    """A write that failed for want of space; what was there before is kept."""


def disk_full(path: Path, error: BaseException) -> DiskFullError:
    """The one-line error of a write of ``path`` that ran out of space (``error`` the system's or a library's)."""
    try:
        free = f"{shutil.disk_usage(path.parent).free / 1e6:.0f} MB free"
    except OSError:
        free = "free space unknown"
    return DiskFullError(f"disk full: cannot write {path} ({free}; {type(error).__name__}: {error}); the previous version is kept: "
                         "free some space and run the command again")


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it is removed (a full
    disk as :class:`DiskFullError`). A ``path`` that is a folder, or whose folder does not exist, is refused
    naming it."""
    path = Path(path)
    if path.is_dir():  # else os.replace fails naming the temporary file, not the user's path
        raise OutputExistsError(f"{path} is a folder: name a file to write")
    if not path.parent.is_dir():
        raise MissingFileError(f"cannot write {path}: its folder {path.parent} does not exist — create it or name another")
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(handle)
    os.chmod(temporary, 0o666 & ~_umask())  # mkstemp makes owner-only files; written files should not be
    try:
        yield Path(temporary)
        os.replace(temporary, path)
    except OSError as error:
        Path(temporary).unlink(missing_ok=True)
        if error.errno in NO_SPACE and not isinstance(error, MmcsplatError):
            raise disk_full(path, error) from error
        raise
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Replace ``path`` with ``text`` (UTF-8) atomically."""
    with atomic_path(path) as temporary:
        temporary.write_text(text, encoding="utf-8")


def write_json_atomic(path: str | os.PathLike, payload: Any) -> None:
    """Replace ``path`` with ``payload`` as indented JSON atomically."""
    write_text_atomic(path, json.dumps(payload, indent=2))


@contextmanager
def new_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``path`` to fill; on success it becomes ``path``, on error it is
    removed: a reader never sees a half-written folder. ``path`` must not exist or be an empty folder
    (an error naming it otherwise: nothing the user made is replaced)."""
    from mmcsplat.plugin_api.errors import OutputExistsError

    path = Path(path)
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise OutputExistsError(f"{path} already exists and is not an empty folder: give a new one")
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(temporary, 0o777 & ~_umask())
    try:
        yield temporary
        if path.exists():
            path.rmdir()
        os.replace(temporary, path)
    except BaseException:
        remove_local_tree(temporary)
        raise


@contextmanager
def replaced_folder(folder: str | os.PathLike, own: Callable[[Path], bool]) -> Iterator[Path]:
    """Yield a temporary folder beside ``folder`` to fill; on success it replaces ``folder`` as a whole (an
    earlier export with more files leaves none behind), on error it is removed: a failed export leaves no file
    that looks whole. ``folder`` may hold only entries ``own`` accepts (what an earlier export wrote): anything
    else is an error naming it, so nothing the user made is replaced."""
    from mmcsplat.plugin_api.errors import NotAFolderError, OutputExistsError

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise NotAFolderError(f"{folder} is a file, not a folder to write into: give a folder")
    strangers = sorted(path.name for path in folder.iterdir() if not own(path)) if folder.is_dir() else []
    if strangers:
        raise OutputExistsError(f"{folder} holds {', '.join(strangers[:3])}{' …' if len(strangers) > 3 else ''}, which no export of this kind "
                                "wrote: it replaces only a folder of its own files — move them or give another folder")
    folder.parent.mkdir(parents=True, exist_ok=True)
    temporary = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
    os.chmod(temporary, 0o777 & ~_umask())
    try:
        yield temporary
        if folder.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".old", dir=folder.parent))
            os.replace(folder, old / folder.name)
            os.replace(temporary, folder)
            remove_local_tree(old)
        else:
            os.replace(temporary, folder)
    finally:
        remove_local_tree(temporary)


def remove_leftovers(folder: Path, prefix: str) -> None:
    """Delete what killed writers left in ``folder``: entries named ``prefix`` + anything (their partial
    or replaced copies). Only a writer holding the lock of what it writes may call it."""
    if folder.is_dir():
        for leftover in folder.glob(f"{glob.escape(prefix)}*"):
            remove_local_tree(leftover)


def remove_local_tree(path: Path) -> None:
    """Delete ``path``, a folder or a file; a folder once the writes in flight into it are done
    (:func:`~mmcsplat.storage.chunks.settle_zarr_io`: an interrupted zarr store is still being written)."""
    if path.is_dir() and not path.is_symlink():
        settle_zarr_io()
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
