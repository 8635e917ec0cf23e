"""The byte-bounded cache of decoded frames a session reader streams through, so memory does not grow
with the length of a session."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from typing import Any

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.memory import release_freed_memory

DEFAULT_CACHE_BYTES = 256 * 2**20
#: Bytes a cache stores between two returns of free memory to the system (one takes a few milliseconds).
TRIM_BYTES = 2 * 2**20


class FrameCache:
    """A least-recently-used cache bounded by the total ``nbytes`` of its values, safe across threads.

    A value larger than the whole budget is never cached; ``hits``, ``misses`` and ``current_bytes`` say
    how it does. After every :data:`TRIM_BYTES` stored, the allocator's free pages go back to the system
    (:func:`mmcsplat.storage.memory.release_freed_memory`): without that, a streamed training run's resident size
    grew to several times the budget.
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 0:
            raise InputError(f"cache budget must be ≥ 0 bytes, got {max_bytes}")
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
