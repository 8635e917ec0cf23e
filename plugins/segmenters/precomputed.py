"""``precomputed``: the masks a session was ingested with (by formats that ship them, such as d3dgs and
D-NeRF, or the synthetic capture's ground truth), post-processed like any other.

It always starts from those masks, never from what an earlier segmentation stored (the session keeps them
as ``source_mask`` once a segmentation replaced them): running it again gives the same masks, and it
brings the capture's masks back after another segmenter."""

from __future__ import annotations

from collections.abc import Iterator

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.segmenters.postprocess import PostProcessedSegmenter, present_frames
from mmcsplat.storage.session import SessionReader


@attrs.frozen
class PrecomputedSegmenter(PostProcessedSegmenter):
    """Yields the masks a camera was ingested with; its labels are left as they are (yielded as ``None``)."""

    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        if not session.has_source_mask(camera):
            raise InputError(
                f"{session.url}: camera {camera!r} has no masks from its capture (the precomputed segmenter "
                "needs the masks written at ingest: choose another segmenter, or ingest the capture again)"
            )
        for t in present_frames(session, camera):
            yield int(t), session.source_mask(int(t), camera), None
