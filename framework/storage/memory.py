"""Giving freed heap memory back to the operating system.

A run that streams frames through a bounded cache keeps decoding frames that live long (in the cache)
between the trainer's short-lived tensors; glibc's allocator then keeps the freed holes between them
mapped, and the process's resident size grows to several times the cache's budget (measured:
docs/performance.md, "Streaming"). ``malloc_trim`` hands every whole free page back.
"""

from __future__ import annotations

import ctypes
import functools


@functools.cache
def malloc_trim_function():
    """glibc's ``malloc_trim``, or ``None`` where the C library has none (macOS, musl, Windows). Looked up
    among the process's own symbols: ``ctypes.util.find_library`` would run ``ldconfig`` to find libc."""
    try:
        return getattr(ctypes.CDLL(None), "malloc_trim", None)
    except (OSError, TypeError):  # Windows has no handle for the process's own symbols
        return None


def release_freed_memory() -> bool:
    """Hand the allocator's free pages back to the operating system; whether any were (never, where the
    C library has no ``malloc_trim``)."""
    trim = malloc_trim_function()
    return trim is not None and bool(trim(0))
