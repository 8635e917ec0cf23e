"""Segment the subject in a session's frames with a segmenter plugin and store the masks (and labels).

The session is updated atomically: the new masks and labels replace the old ones all at once when every
selected camera is done, and a failure or interruption leaves the session exactly as it was.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import attrs

from mmcsplat.configuration.registry import default_registry


@attrs.frozen
class CameraSummary:
    """What one camera's segmentation produced: frames written, how many masks are empty, and the mean
    fraction of the image the masks cover."""

    camera: str
    frames: int
    empty: int
    coverage: float


def segment_session(
    url: str | os.PathLike,
    segmenter: str,
    params: Mapping[str, Any] | None = None,
    cameras: Sequence[str] | None = None,
    progress: bool = True,
) -> list[CameraSummary]:
    """Run the registered ``segmenter`` (built with ``params``) on ``cameras`` of the session at ``url``
    (default: all, held-out ones included: evaluation needs their masks) and write its masks, and labels
    where it yields them, through one :class:`~mmcsplat.storage.session.SessionUpdater` commit."""
    from tqdm import tqdm

    from mmcsplat.storage.session import SessionReader, SessionUpdater

    session = SessionReader(url)
    selected = list(dict.fromkeys(cameras or session.camera_names))
    for camera in selected:
        session.camera(camera)  # an unknown camera is an error naming the session and camera
    instance = default_registry().create("segmenter", segmenter, **dict(params or {}))
    summaries = []
    total = sum(int(session.present(camera).sum()) for camera in selected)
    with SessionUpdater(url) as updater, tqdm(total=total, unit="frame", desc=f"segment ({segmenter})", disable=not progress) as bar:
        for camera in selected:
            frames = empty = 0
            covered = 0.0
            for t, mask, labels in instance.segment(session, camera):
                updater.write(camera, "mask", t, mask)
                if labels is not None:
                    updater.write(camera, "labels", t, labels)
                frames += 1
                empty += not mask.any()
                covered += float(mask.mean())
                bar.update()
            summaries.append(CameraSummary(camera, frames, empty, covered / max(frames, 1)))
    return summaries
