"""Load pickles that other tools write as plain data, without running what a pickle may name.

Unpickling calls whatever class or function the pickle names, so a crafted file runs code. The tools
whose files mmcsplat reads pickle plain containers (DeepLabCut's column labels) or dicts of numpy
arrays (OpenCap's calibration): :func:`load_plain` builds those and refuses any other name.
"""

from __future__ import annotations

import io
import pickle
from typing import Any

import numpy as np

#: The (module, name) pairs a pickle of numpy arrays names: the array's rebuild function (under numpy's
#: private core module, ``numpy.core`` before NumPy 2, ``numpy._core`` since), the array and dtype types.
NUMPY_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"): np.ndarray.__reduce__(np.zeros(0))[0],
    ("numpy._core.multiarray", "_reconstruct"): np.ndarray.__reduce__(np.zeros(0))[0],
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
}


class _PlainUnpickler(pickle.Unpickler):
    """Builds containers, strings and numbers, and numpy arrays where ``arrays``; refuses any other name."""

    def __init__(self, data: bytes, arrays: bool) -> None:
        super().__init__(io.BytesIO(data))
        self._arrays = arrays

    def find_class(self, module: str, name: str) -> Any:
        if self._arrays and (module, name) in NUMPY_GLOBALS:
            return NUMPY_GLOBALS[module, name]
        raise pickle.UnpicklingError(f"it refers to {module}.{name}")


def load_plain(data: bytes, arrays: bool = False) -> Any:
    """The object pickled in ``data``: lists, tuples, dicts, strings and numbers, and numpy arrays when
    ``arrays``. A pickle naming anything else raises :class:`pickle.UnpicklingError` naming it; a
    truncated one ``EOFError`` or ``UnpicklingError``."""
    return _PlainUnpickler(data, arrays).load()
