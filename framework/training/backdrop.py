"""What a fit composites its renders over, and what a masked target shows outside the subject: one
background colour, or each camera's clean plate (the empty scene, stored with the session at ingest).

Over a plate, the pixels on the subject's outline — which mix the subject with the mat behind it — are
reproduced as the camera saw them; over a colour they can only mix with that colour. Renders are made
over black and composited here, so every backend serves both.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError

if TYPE_CHECKING:
    from mmcsplat.storage.session import SessionReader

#: The ``fit.background`` value that composites over each camera's clean plate.
PLATE = "plate"

Background = tuple[float, float, float] | str


def parse_background(value: str | Sequence[float]) -> Background:
    """``fit.background`` checked: ``"plate"`` or three finite numbers (an RGB colour in [0, 1])."""
    if isinstance(value, str):
        if value != PLATE:
            raise InputError(f"fit.background must be {PLATE!r} or an RGB colour [r, g, b], got {value!r}")
        return PLATE
    colour = tuple(float(v) for v in value)
    if len(colour) != 3 or not all(np.isfinite(colour)):
        raise InputError(f"fit.background must be {PLATE!r} or an RGB colour [r, g, b], got {list(value)!r}")
    return colour  # type: ignore[return-value]


def camera_backdrop(background: Background, session: SessionReader, camera: str) -> torch.Tensor:
    """What ``camera``'s renders are composited over: [3] for a colour, [H, W, 3] in [0, 1] for its plate.
    A plate fit on a session without that camera's plate is an error that says how to add plates."""
    if background != PLATE:
        return torch.tensor(background, dtype=torch.float32)
    plate = session.plate(camera)
    if plate is None:
        raise InputError(
            f"fit.background = {PLATE!r}, but session {session.url} has no clean plate of camera {camera!r}: "
            f"estimate the plates from the sequence with `mmcsplat plates {session.url}` (a capture recorded without an empty "
            "scene), or ingest the capture again with its recorded plates (a plates/ folder of the capture, or --plates DIR)"
        )
    return torch.from_numpy(plate.astype(np.float32) / 255.0)
