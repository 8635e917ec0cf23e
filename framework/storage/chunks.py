"""Reading zarr arrays without mistaking lost data for zeros.

zarr returns an array's fill value for a chunk that is not stored, so a deleted or never-synced chunk
file would read as a black image, an empty mask or a Gaussian at the origin. Every store here writes
each chunk it means to keep (``write_empty_chunks``), so a missing chunk under a selection that should
hold data is damage: :func:`read_stored` checks the chunks it reads exist and turns a decoding failure
(a corrupt, truncated chunk) into an error naming the array and index.
"""

from __future__ import annotations

import asyncio
import itertools
import sys
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError

#: How long a store's removal, or a command's exit, waits for zarr's reads and writes still in flight.
SETTLE_SECONDS = 30.0


def settle_zarr_io(timeout: float = SETTLE_SECONDS) -> None:
    """Wait until zarr's reads and writes still in flight are done. zarr runs each on its own IO thread's event
    loop; Ctrl-C stops the caller's wait, not the work, so a partial store removed at once races its last
    chunks (an error "directory not empty" instead of the interrupt, a chunk written into a folder just
    removed), and an exit beside a read or write in flight prints "Task was destroyed but it is pending!" and a
    traceback. Nothing to wait for unless zarr was used."""
    sync = sys.modules.get("zarr.core.sync")
    io_loop = sync.loop[0] if sync is not None else None  # zarr's IO loop, once any store was written or read
    if io_loop is None or io_loop.is_closed() or not io_loop.is_running():
        return

    async def others() -> None:
        pending = asyncio.all_tasks() - {asyncio.current_task()}
        if pending:
            await asyncio.wait(pending, timeout=timeout)

    asyncio.run_coroutine_threadsafe(others(), io_loop).result(timeout + 1)


class DamagedStoreError(InputError):
    """A chunk that should be stored is missing or does not decode."""


def open_stored(group: Any, path: str, where: str) -> Any:
    """The array at ``path`` in ``group``; missing or garbled metadata is an error naming it."""
    try:
        return group[path]
    except KeyError as error:
        raise DamagedStoreError(f"{where}: array {path} is missing from the store (its zarr.json is gone); the store is damaged") from error
    except ValueError as error:  # json.JSONDecodeError and zarr's metadata errors are ValueErrors
        raise DamagedStoreError(f"{where}: the metadata of array {path} is garbled ({error}); the store is damaged") from error


def read_stored(array: Any, index: int | None, where: str) -> np.ndarray:
    """``array[index]`` along the first axis (the whole array for ``None``), refusing missing or corrupt
    chunks; ``where`` names what is read in errors (e.g. "session S: camera 'cam_1' rgb, frame 4")."""
    from zarr.core.sync import sync

    chunks, grid = array.chunks, array.cdata_shape
    first = range(grid[0]) if index is None else [index // chunks[0]]
    for coords in itertools.product(first, *(range(n) for n in grid[1:])):
        key = array.metadata.encode_chunk_key(coords)
        if not sync(array.store.exists(f"{array.path}/{key}")):
            raise DamagedStoreError(f"{where}: its data is missing from the store (chunk {array.path}/{key} is gone); the store is damaged")
    try:
        return array[...] if index is None else array[index]
    except (RuntimeError, ValueError, OSError) as error:  # numcodecs/zstd raise RuntimeError on corrupt input
        raise DamagedStoreError(f"{where}: its stored data does not decode ({error}); the store is damaged") from error
