"""One writer at a time: an advisory file lock (filelock) held while a run directory or a session is
written, so that a second writer fails at once with an error naming what is busy instead of racing the
first and silently losing one result. The operating system releases the lock when its process dies,
so a killed writer never leaves its run or session locked."""

from __future__ import annotations

import os
from pathlib import Path

import filelock

from mmcsplat.plugin_api.errors import MmcsplatError

#: The lock file inside a run directory.
RUN_LOCK = ".mmcsplat.lock"


class BusyError(MmcsplatError):
    """Another process is writing the same run or session."""


class WriterLock:
    """Holds the lock at ``path`` from construction to :meth:`release` (or the end of a ``with``)."""

    def __init__(self, path: Path, what: str) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._lock = filelock.FileLock(path, timeout=0)
        try:
            self._lock.acquire()
        except filelock.Timeout as error:
            raise BusyError(f"{what} is being written by another mmcsplat process (lock {path}): wait for it to finish, or stop it") from error

    def release(self) -> None:
        """Let the next writer in, leaving no lock file behind; idempotent. (A writer that opened the file
        just before it is unlinked could lock the orphaned inode while a third locks a new file; writers
        do not wait for the lock, so that takes three starting within microseconds.)"""
        if self._lock.is_locked:
            self.path.unlink(missing_ok=True)
            self._lock.release()

    def __enter__(self) -> WriterLock:
        return self

    def __exit__(self, *_: object) -> None:
        self.release()


def run_lock(run: Path) -> WriterLock:
    """The writer lock of a run directory (created if needed)."""
    run = Path(run)
    return WriterLock(run / RUN_LOCK, f"run {run}")


def session_lock(target: Path) -> WriterLock:
    """The writer lock of the local session at ``target``: a file beside it, since ingest replaces the
    session's folder as a whole."""
    target = Path(os.path.abspath(target))
    return WriterLock(target.parent / f".{target.name}.lock", f"session {target}")
