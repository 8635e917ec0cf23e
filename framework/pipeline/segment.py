"""Segment the subject in a session's frames with a segmenter plugin and store the masks (and labels).

The session is updated atomically: the new masks and labels replace the old ones all at once when every
selected camera is done, and a failure or interruption leaves the session exactly as it was. With
``consistent``, each mask then keeps only the pixels the other cameras' masks agree on
(:func:`mmcsplat.analysis.visual_hull.consistent_mask`): what a single segmenter finds in one view — a
bystander at the edge of the picture, a shadow — is dropped because no other camera sees it as subject.

Masks that are near-empty or near-full in most cameras stop the step before anything is written
(:func:`check_plausible`): a fit from them ends in the visual-hull initializer's error, far from its cause.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np

from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.training.plugin_hooks import plugin_hook

if TYPE_CHECKING:  # imported on use: the CLI parser imports this module for every command
    from mmcsplat.configuration.config import PluginChoice
    from mmcsplat.plugin_api.interfaces import Segmenter
    from mmcsplat.storage.session import SessionReader, SessionUpdater


#: Mean shares of the image below and above which a camera's masks are implausible: a subject a rig films
#: covers a few per cent of a view or more (the synthetic infant 3–4 % at 256 × 192, the Pose2Sim adult
#: 3–6 %); the failures of issue 25 covered 0–0.8 %, or all of it.
NEAR_EMPTY, NEAR_FULL = 0.01, 0.9


@attrs.frozen
class BuiltSegmenter:
    """A segmenter plugin under its registered name, built once (a model loaded once): ``mmcsplat run`` builds
    the user's segmenter to check it before ingest, then segments the session with that same plugin."""

    name: str
    plugin: Segmenter

    @classmethod
    def of(cls, choice: PluginChoice) -> BuiltSegmenter:
        """The segmenter ``choice`` names, built."""
        return cls(choice.name, choice.build())


@attrs.frozen
class CameraSummary:
    """What one camera's segmentation produced: frames written, how many masks are empty, and the mean
    fraction of the image the masks cover."""

    camera: str
    frames: int
    empty: int
    coverage: float

    @property
    def plausible(self) -> bool:
        """Whether the masks cover between :data:`NEAR_EMPTY` and :data:`NEAR_FULL` of the images on average."""
        return NEAR_EMPTY <= self.coverage <= NEAR_FULL


def check_plausible(url: str | os.PathLike, segmenter: str, summaries: Sequence[CameraSummary]) -> None:
    """Raise an :class:`InputError` naming the cameras when the masks of most of them are implausible
    (:attr:`CameraSummary.plausible`), saying what to do."""
    wrong = [summary for summary in summaries if summary.frames and not summary.plausible]
    if len(wrong) * 2 <= len(summaries):
        return
    cameras = ", ".join(f"{summary.camera} {summary.coverage:.1%}" for summary in wrong)
    raise InputError(
        f"session {url}: segmenter {segmenter!r} made implausible masks in {len(wrong)} of {len(summaries)} cameras (mean share of the "
        f"image: {cameras}; a subject covers {NEAR_EMPTY:.0%}–{NEAR_FULL:.0%}): nothing was written — bring masks, keypoints (--keypoints) "
        "or clean plates with the capture, or choose another segmenter or its settings (`mmcsplat plugins --show NAME`)"
    )


def segment_session(
    url: str | os.PathLike,
    segmenter: str | BuiltSegmenter,
    params: Mapping[str, Any] | None = None,
    cameras: Sequence[str] | None = None,
    progress: bool = True,
    consistent: bool = False,
    check: bool = True,
) -> list[CameraSummary]:
    """Run the registered ``segmenter`` (built with ``params``, or already built, when ``params`` must be empty) on ``cameras`` of the session at ``url``
    (default: all, held-out ones included: evaluation needs their masks) and write its masks, and labels
    where it yields them, through one :class:`~mmcsplat.storage.session.SessionUpdater` commit; with
    ``check``, masks implausible in most cameras raise instead (:func:`check_plausible`)."""
    from tqdm import tqdm

    from mmcsplat.storage.session import SessionReader, SessionUpdater

    session = SessionReader(url)
    selected = list(dict.fromkeys(cameras or session.camera_names))
    for camera in selected:
        session.camera(camera)  # an unknown camera is an error naming the session and camera
    if isinstance(segmenter, BuiltSegmenter):
        if params:  # a built plugin already holds its parameters: these would be silently unused
            raise ValueError(f"segment_session: segmenter {segmenter.name!r} is already built; its parameters cannot be given again ({dict(params)})")
        segmenter, instance = segmenter.name, segmenter.plugin
    else:
        instance = default_registry().create("segmenter", segmenter, **dict(params or {}))
    if consistent and len(selected) < 3:
        raise InputError(f"session {session.url}: multi-view consistency needs masks of at least 3 cameras, got {len(selected)}")
    total = sum(int(session.present(camera).sum()) for camera in selected)
    with SessionUpdater(url) as updater:
        with tqdm(total=total, unit="frame", desc=f"segment ({segmenter})", disable=not progress) as bar:
            for camera in selected:
                with plugin_hook("segmenter", segmenter, "segment"):
                    for t, mask, labels in instance.segment(session, camera):
                        updater.write(camera, "mask", t, mask)
                        if labels is not None:
                            updater.write(camera, "labels", t, labels)
                        bar.update()
        if consistent:
            _keep_what_the_others_see(session, updater, selected, progress)
        summaries = [_summary(session, updater, camera) for camera in selected]
        if check:
            check_plausible(session.url, segmenter, summaries)  # inside the update: nothing is committed
        return summaries


def _keep_what_the_others_see(session: SessionReader, updater: SessionUpdater, cameras: Sequence[str], progress: bool) -> None:
    """Replace every written mask by its multi-view consistent part, frame by frame."""
    from tqdm import tqdm

    from mmcsplat.analysis.visual_hull import consistent_mask
    from mmcsplat.scene.rig import rig_center, rig_scale

    center = rig_center(session.cameras)
    radius = rig_scale(session.cameras, center)
    for t in tqdm(range(session.num_frames), unit="frame", desc="multi-view consistency", disable=not progress):
        masks = {camera: updater.pending(camera, "mask")[t] for camera in cameras if session.present(camera)[t]}
        views = [(session.camera(camera), mask) for camera, mask in masks.items()]
        for index, (camera, mask) in enumerate(views):
            others = views[:index] + views[index + 1:]
            updater.write(camera.name, "mask", t, consistent_mask(camera, mask, others, center, radius) if len(others) >= 2 else mask)


def _summary(session: SessionReader, updater: SessionUpdater, camera: str) -> CameraSummary:
    masks = updater.pending(camera, "mask")
    coverages = [float(masks[int(t)].mean()) for t in np.flatnonzero(session.present(camera))]
    return CameraSummary(camera, len(coverages), sum(c == 0 for c in coverages), float(np.mean(coverages)) if coverages else 0.0)
