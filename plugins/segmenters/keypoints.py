"""``keypoints``: subject masks from 2D keypoints (OpenPose JSON, as Pose2Sim users already have; SLEAP or
DeepLabCut files, as animal labs have), for captures with no clean plate and no segmentation model.

Each frame's detections are drawn filled, in one of three shapes chosen by what the keypoints name:

- a human skeleton (the keypoints include shoulders and hips by OpenPose's names): the torso as the
  polygon of shoulders and hips, each limb as a thick segment, the head as a disk — widths in proportion
  to the subject's torso length in that camera (median over the frames), so near and far views get
  alike masks; keypoints without a neck or a head's centre (MediaPipe's, COCO's) get them between the
  shoulders and between the ears, so the neck joins the head to the torso, and a head whose centre and
  nose are not seen is drawn around its eyes and ears;
- any other skeleton the file declares (a SLEAP skeleton's edges: a mouse's nose–head–spine–tail): each
  edge as a thick segment and each keypoint as a disk, as wide as ``BODY_WIDTH`` of the keypoints'
  extent (the largest distance between two of a frame's keypoints, median over the frames);
- keypoints without a skeleton (DeepLabCut files declare none): the convex hull of the frame's keypoints
  with the same disks around each, since the keypoints lie inside the body, not on its outline.

This coarse silhouette is already a mask (``refine = "none"``). With a clean plate (recorded, or estimated
by ``mmcsplat plates`` with these masks excluding the subject), ``refine = "plate"`` keeps the pixels that
differ from the plate within the silhouette grown by ``margin``: the body's true outline, and never a
bystander or a moving object away from the subject, which plate differences alone would take. A human's
torso (``torso``: the polygon of shoulders and hips, inside the body) is kept whatever the plate shows: an
estimated plate keeps what barely moved, and the Pose2Sim demo's cam_01 and cam_02 plates hold a ghost of
the trunk that the refinement cut out of the masks (docs/real-data.md, "Masks and plates without a model").
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import attrs
import cv2
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import above, at_least, one_of, parameter
from mmcsplat.plugin_api.registration import PluginBuilder
from mmcsplat.plugins.segmenters.postprocess import KEEP, PostProcessedSegmenter, dilate, open_close, present_frames
from mmcsplat.scene.human_skeleton import HEAD, LIMB_BONES, TORSO, with_midpoints
from mmcsplat.scene.human_skeleton import torso_length as human_torso_length
from mmcsplat.storage.session import SessionReader

#: Limbs drawn as thick segments, by keypoint name (pairs naming a keypoint the model lacks are skipped).
LIMBS = (*LIMB_BONES,
         ("LAnkle", "LHeel"), ("LAnkle", "LBigToe"), ("LHeel", "LBigToe"), ("RAnkle", "RHeel"), ("RAnkle", "RBigToe"), ("RHeel", "RBigToe"),
         ("Neck", "Head"), ("Neck", "Nose"))
#: Widths as shares of the torso length (neck to mid-hip): an adult's thigh is about a third of it.
LIMB_WIDTH = 0.3
HEAD_RADIUS = 0.3
#: The body's width as a share of the keypoints' extent, for skeletons other than a human's: a mouse is
#: about a third as wide as it is long from nose to tail base.
BODY_WIDTH = 0.3


def torso_length(observed: KeypointObservations) -> float | None:
    """Median pixel distance from the neck (mid-shoulders) to the mid-hips over the frames that show both."""
    index = {name: j for j, name in enumerate(observed.names)}
    if not all(name in index for name in TORSO):
        return None
    points, seen = observed.pixels, observed.confidence > 0
    visible = seen[:, [index[name] for name in TORSO]].all(axis=1)
    lengths = human_torso_length(lambda name: points[:, index[name]])
    return float(np.median(lengths[visible])) if visible.any() else None


def is_human(names: tuple[str, ...]) -> bool:
    """Whether the keypoints include the torso's by OpenPose's names (drawn as a human skeleton)."""
    return all(name in names for name in TORSO)


def midpoint_keypoints(observed: KeypointObservations) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """The observations' names, pixels [T, K', 2] and seen [T, K'] with the joints
    :func:`~mmcsplat.scene.human_skeleton.with_midpoints` adds (a neck for MediaPipe's or COCO's keypoints), seen where
    both ends are."""
    seen = observed.confidence > 0
    joints = with_midpoints({name: np.where(seen[:, j, None], observed.pixels[:, j], np.nan) for j, name in enumerate(observed.names)})
    pixels = np.stack(list(joints.values()), axis=1)
    shown = np.isfinite(pixels).all(axis=-1)
    return tuple(joints), np.where(shown[..., None], pixels, 0.0), shown


def extent(observed: KeypointObservations) -> float | None:
    """Median over the frames showing two keypoints or more of the largest pixel distance between two of them."""
    spans = []
    for points, seen in zip(observed.pixels, observed.confidence > 0, strict=True):
        if seen.sum() >= 2:
            shown = points[seen]
            spans.append(np.linalg.norm(shown[:, None] - shown[None], axis=-1).max())
    return float(np.median(spans)) if spans else None


def _fixed(pixels: np.ndarray) -> np.ndarray:
    """Pixels as cv2's shift=4 sub-pixel integer points."""
    return np.round(pixels * 16).astype(np.int64).clip(-(2**27), 2**27).astype(np.int32)


def outline_mask(pixels: np.ndarray, seen: np.ndarray, names: tuple[str, ...], edges: tuple[tuple[str, str], ...],
                 shape: tuple[int, int], scale: float) -> np.ndarray:
    """[H, W] bool: one frame's keypoints of a non-human skeleton, filled (module docstring): its ``edges``
    drawn thick, or without edges the keypoints' convex hull; a disk around each keypoint. ``scale``: the extent."""
    index = {name: j for j, name in enumerate(names)}
    canvas = np.zeros(shape, dtype=np.uint8)
    fixed = _fixed(pixels)
    width = max(1, round(BODY_WIDTH * scale))
    if edges:
        for a, b in edges:
            if a in index and b in index and seen[index[a]] and seen[index[b]]:
                cv2.line(canvas, tuple(fixed[index[a]]), tuple(fixed[index[b]]), 1, width, cv2.LINE_AA, shift=4)
    elif seen.sum() >= 3:
        cv2.fillPoly(canvas, [cv2.convexHull(fixed[seen])], 1, cv2.LINE_AA, shift=4)
    for point in fixed[seen]:
        cv2.circle(canvas, tuple(point), round(width * 8), 1, -1, cv2.LINE_AA, shift=4)  # radius width / 2, in 1/16 px
    return canvas.astype(bool)


def torso_mask(pixels: np.ndarray, seen: np.ndarray, names: tuple[str, ...], shape: tuple[int, int]) -> np.ndarray:
    """[H, W] bool: the polygon of one frame's shoulders and hips among ``pixels`` [K, 2] (``seen`` [K] bool);
    empty unless all four are seen."""
    index = {name: j for j, name in enumerate(names)}
    canvas = np.zeros(shape, dtype=np.uint8)
    if all(name in index and seen[index[name]] for name in TORSO):
        cv2.fillPoly(canvas, [_fixed(pixels)[[index[name] for name in TORSO]]], 1, cv2.LINE_AA, shift=4)
    return canvas.astype(bool)


def skeleton_mask(pixels: np.ndarray, seen: np.ndarray, names: tuple[str, ...], torso: np.ndarray, scale: float) -> np.ndarray:
    """[H, W] bool: the filled skeleton of one frame's keypoints ``pixels`` [K, 2] (``seen`` [K] bool): its
    limbs and head drawn over ``torso``, the same keypoints' :func:`torso_mask`."""
    index = {name: j for j, name in enumerate(names)}
    canvas = torso.astype(np.uint8)
    fixed = _fixed(pixels)

    def usable(name: str) -> bool:
        return name in index and bool(seen[index[name]])

    width = max(1, round(LIMB_WIDTH * scale))
    for a, b in LIMBS:
        if usable(a) and usable(b):
            cv2.line(canvas, tuple(fixed[index[a]]), tuple(fixed[index[b]]), 1, width, cv2.LINE_AA, shift=4)
    # The head's centre, else the nose; else the eyes' and ears' mean, off the centre but on the head (a head seen from
    # behind shows only its ears, and without a disk the head leaves that view's mask).
    centre = next((pixels[index[name]] for name in HEAD[:2] if usable(name)), None)
    rest = [pixels[index[name]] for name in HEAD[2:] if usable(name)]
    if centre is None and rest:
        centre = np.mean(rest, axis=0)
    if centre is not None:
        cv2.circle(canvas, tuple(_fixed(centre)), round(HEAD_RADIUS * scale * 16), 1, -1, cv2.LINE_AA, shift=4)
    return canvas.astype(bool)


@attrs.frozen
class KeypointSegmenter(PostProcessedSegmenter):
    """Masks from the filled skeleton (or hull) of 2D keypoints, optionally refined against the camera's clean plate."""

    source: str | Mapping[str, Any] = parameter(
        "openpose", doc='the landmarks plugin giving the 2D keypoints (openpose, sleap, deeplabcut): its name, or a table of name and parameters '
            '({ name = "openpose", folder = "pose_2d" }, { name = "sleap", files = ["cam1.analysis.h5", …] })')
    refine: str = parameter("none", doc="none: the skeleton is the mask; plate: what differs from the clean plate inside it", validator=one_of("none", "plate"))
    margin: float = parameter(0.3, doc="plate: the skeleton grown by this share of its size (torso length, or the keypoints' extent) bounds the mask",
                              validator=at_least(0))
    threshold: float = parameter(20.0, doc="plate: grey levels of difference from the plate that count as subject", validator=above(0))
    torso: bool = parameter(True, doc="plate: a human's torso (the polygon of shoulders and hips) is kept whatever the plate shows, since "
                            "an estimated plate may hold a trunk that barely moved")
    # Every piece of a mask bounded by the skeleton is the subject: refined against the plate, a body often
    # splits at the belt or the knees (the Pose2Sim demo's cam_01 kept only its legs as the central piece).
    keep: str = parameter("all", doc="the mask's component kept: all (the skeleton bounds the mask), central or largest",
                          validator=one_of(*KEEP))
    registry: PluginBuilder = attrs.field(kw_only=True, repr=False)

    def _observations(self, session: SessionReader, camera: str) -> KeypointObservations:
        options = {"name": self.source} if isinstance(self.source, str) else dict(self.source)
        name = options.pop("name", None)
        if not isinstance(name, str):
            raise InputError(f"segmenter 'keypoints': source must be a landmarks plugin's name or a table with a 'name', got {self.source!r}")
        plugin = self.registry.create("landmarks", name, **options)
        found = [o for o in plugin.observations(session, range(session.num_frames)) if o.camera == camera]
        if not found:
            raise InputError(f"segmenter 'keypoints': the {name} source has no keypoints for camera {camera!r}")
        return found[0]

    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        observed = self._observations(session, camera)
        human = is_human(observed.names)
        scale = torso_length(observed) if human else extent(observed)
        if scale is None:
            shown = "shoulders and hips together" if human else "two keypoints in one frame"
            raise InputError(f"segmenter 'keypoints': camera {camera!r} never shows {shown}; its masks cannot be sized")
        stored = session.camera(camera)
        plate = session.plate(camera) if self.refine == "plate" else None
        if self.refine == "plate" and plate is None:
            raise InputError(f"{session.url}: camera {camera!r} has no clean plate for refine = \"plate\": estimate one with "
                             f"`mmcsplat plates {session.url}` after segmenting with refine = \"none\"")
        names, pixels, shown = midpoint_keypoints(observed) if human else (observed.names, observed.pixels, observed.confidence > 0)
        for t in present_frames(session, camera):
            where = np.flatnonzero(observed.frames == t)
            if not len(where):
                yield int(t), np.zeros((stored.height, stored.width), dtype=bool), None
                continue
            k = where[0]
            seen, shape = shown[k], (stored.height, stored.width)
            torso = torso_mask(pixels[k], seen, names, shape) if human else None
            mask = skeleton_mask(pixels[k], seen, names, torso, scale) if torso is not None else \
                outline_mask(pixels[k], seen, names, observed.edges, shape, scale)
            if plate is not None:
                difference = np.abs(session.frame(int(t), camera).rgb.astype(np.int16) - plate.astype(np.int16)).max(axis=-1)
                mask = open_close(difference > self.threshold, 1, 2) & dilate(mask, round(self.margin * scale))
                if self.torso and torso is not None:
                    mask |= torso
            yield int(t), mask, None
