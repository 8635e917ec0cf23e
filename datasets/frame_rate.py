"""The frame rate of a capture whose files state none (image folders, a COLMAP video layout, a nerfstudio
``transforms.json`` without times): the reader's ``fps`` parameter when given, else 30, said with a
warning when the capture has more than one frame, since a tracker's steps a frame follow the rate
(``iterative``'s ``auto``: 100 at 30 fps, 50 at 60) and a wrong rate would change them unseen.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import attrs

from mmcsplat.plugin_api.parameters import finite_positive, parameter

#: The frame rate assumed where neither the capture nor the reader's ``fps`` states one.
DEFAULT_FPS = 30.0
#: The ``fps`` parameter of the readers whose files carry no frame rate.
FPS_PARAMETER = parameter(None, doc=f"the capture's frame rate, frames per second (none: {DEFAULT_FPS:g}, with a warning when the capture "
                          "has several frames)", converter=attrs.converters.optional(float), validator=finite_positive)


def stated_or_assumed(fps: float | None, frames: int, source: Path | str) -> float:
    """``fps``, or for ``None`` :data:`DEFAULT_FPS`, with a warning naming ``source`` when the capture has
    several ``frames`` (a single frame has no rate to get wrong)."""
    if fps is not None:
        return fps
    if frames > 1:
        warnings.warn(f"{source}: the capture states no frame rate; assuming {DEFAULT_FPS:g} fps (give the reader's fps: "
                      "`mmcsplat run --reader-set fps=N`, `mmcsplat ingest --set fps=N`)", stacklevel=3)
    return DEFAULT_FPS
