"""``precomputed``: the masks a session already holds (written at ingest by formats that ship them, such
as d3dgs and D-NeRF, or the synthetic capture's ground truth), post-processed like any other."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from mmcsplat.store import SessionReader

from .postprocess import PostProcessedSegmenter, present_frames


class PrecomputedSegmenter(PostProcessedSegmenter):
    """Yields the session's own masks of a camera; its labels are left as they are (yielded as ``None``)."""

    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        if not session.has("mask", camera):
            raise ValueError(
                f"{session.url}: camera {camera!r} has no masks to use (the precomputed segmenter needs masks "
                "written at ingest; choose another segmenter)"
            )
        for t in present_frames(session, camera):
            yield int(t), session.frame(int(t), camera).mask, None
