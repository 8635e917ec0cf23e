"""Writes that become visible all at once or not at all: the transaction every store writer is."""

from __future__ import annotations

from abc import ABC, abstractmethod


class Transaction(ABC):
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
