"""Mask post-processing shared by every built-in segmenter, and the base class that applies it."""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Iterator

import attrs
import cv2
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Segmenter
from mmcsplat.plugin_api.parameters import at_least, between, one_of, parameter
from mmcsplat.scene.rig import rig_center
from mmcsplat.storage.session import SessionReader

#: Mask pieces at most twice this many background pixels apart are one component: on the synthetic
#: capture at 256 × 192 a forearm is cut off the body by a 1 px gap in 12 of its 240 ground-truth masks.
BRIDGE_PX = 1


def _disk(radius: int) -> np.ndarray:
    """An elliptical structuring element of the given radius in pixels."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _components(mask: np.ndarray, bridge: int) -> tuple[int, np.ndarray]:
    """(count including the background, labels) of the 8-connected components of ``mask``, pieces at most
    2 × ``bridge`` background pixels apart counting as one."""
    return cv2.connectedComponents(dilate(mask, bridge).astype(np.uint8), connectivity=8)


def largest_component(mask: np.ndarray, bridge: int = 0) -> np.ndarray:
    """Only the largest 8-connected component of ``mask`` [H, W] bool (an empty mask stays empty), where
    pieces separated by at most 2 × ``bridge`` background pixels count as connected (each grows by
    ``bridge`` before the pieces are labelled): a limb thinner than a pixel at the image's resolution can
    cut a hand or forearm off the body's silhouette, and dropping it makes the views' masks disagree about
    the subject. The result keeps only pixels of ``mask``."""
    mask = mask.astype(bool)
    count, labels = _components(mask, bridge)
    if count <= 2:  # background alone, or one component
        return mask.copy()
    area = np.bincount(labels[mask], minlength=count)  # a component's size counts only the mask's own pixels
    return mask & (labels == 1 + int(np.argmax(area[1:])))


def large_components(mask: np.ndarray, share: float, bridge: int = 0) -> np.ndarray:
    """The components of ``mask`` (connected as in :func:`largest_component`) at least ``share`` of the largest
    one's size: the pieces of a body split in an image, without the specks beside it."""
    mask = mask.astype(bool)
    count, labels = _components(mask, bridge)
    if count <= 2:
        return mask.copy()
    area = np.bincount(labels[mask], minlength=count)
    area[0] = 0
    return mask & (area[labels] >= share * area.max())


def central_component(mask: np.ndarray, point: np.ndarray, bridge: int = 0) -> np.ndarray:
    """Only the component of ``mask`` (connected as in :func:`largest_component`) with a pixel nearest to
    ``point`` (u, v) — where the rig's centre projects, since a rig's cameras aim at their subject. A
    bystander at the edge of a view is dropped even when it is larger there than the subject (the
    synthetic capture's adult leg in cam_0 and cam_1)."""
    mask = mask.astype(bool)
    count, labels = _components(mask, bridge)
    if count <= 2:
        return mask.copy()
    rows, columns = np.nonzero(mask)
    distance = np.hypot(columns - point[0], rows - point[1])
    nearest = np.full(count, np.inf)
    np.minimum.at(nearest, labels[rows, columns], distance)
    return mask & (labels == int(np.argmin(nearest)))


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """``mask`` grown by ``radius`` pixels (a disk); radius 0 returns a copy."""
    if radius == 0:
        return mask.astype(bool, copy=True)
    return cv2.dilate(mask.astype(np.uint8), _disk(radius)).astype(bool)


def open_close(mask: np.ndarray, open_radius: int, close_radius: int) -> np.ndarray:
    """Morphological opening (removes specks) then closing (fills pinholes), each skipped at radius 0."""
    result = mask.astype(np.uint8)
    if open_radius:
        result = cv2.morphologyEx(result, cv2.MORPH_OPEN, _disk(open_radius))
    if close_radius:
        result = cv2.morphologyEx(result, cv2.MORPH_CLOSE, _disk(close_radius))
    return result.astype(bool)


def _non_negative(instance: object, attribute: attrs.Attribute, value: int) -> None:
    if value < 0:
        raise InputError(f"{attribute.name} must be ≥ 0 pixels, got {value}")


#: What :class:`PostProcess` keeps of a mask: one component (the central or the largest), or all of it.
KEEP = ("central", "largest", "all")


@attrs.frozen
class PostProcess:
    """The clean-up applied to every raw mask: keep one connected component — the one nearest the rig's
    centre in the view (``central``) or the largest (``largest``; the reference study removed
    experimenters' legs this way) — or ``all`` but the pieces under ``min_piece`` of the largest, pieces at
    most 2 × ``bridge`` pixels apart counting as connected; then dilate by ``dilation`` pixels."""

    keep: str = attrs.field(default="central", validator=attrs.validators.in_(KEEP))
    dilation: int = attrs.field(default=0, converter=int, validator=_non_negative)
    bridge: int = attrs.field(default=BRIDGE_PX, converter=int, validator=_non_negative)
    min_piece: float = attrs.field(default=0.0, converter=float, validator=[attrs.validators.ge(0.0), attrs.validators.le(1.0)])

    def __call__(self, mask: np.ndarray, centre: np.ndarray | None = None) -> np.ndarray:
        """The cleaned-up copy of ``mask`` [H, W] bool; ``centre`` (u, v) is where the rig's centre projects
        (``central`` keeps the largest component without it)."""
        if self.keep == "central" and centre is not None:
            mask = central_component(mask, centre, self.bridge)
        elif self.keep != "all":
            mask = largest_component(mask, self.bridge)
        elif self.min_piece:
            mask = large_components(mask, self.min_piece, self.bridge)
        return dilate(mask, self.dilation)


@attrs.define
class PostProcessedSegmenter(Segmenter):
    """A segmenter whose raw masks go through :class:`PostProcess`; subclasses implement :meth:`raw`."""

    keep: str = parameter("central", doc="the mask's component kept: central (nearest where the rig's centre projects: the cameras aim "
                                         "at the subject), largest, or all", validator=one_of(*KEEP))
    dilation: int = parameter(0, doc="grow the mask by this many pixels", validator=at_least(0))
    bridge: int = parameter(BRIDGE_PX, doc="pieces at most 2 × bridge pixels apart count as one component", validator=at_least(0))
    min_piece: float = parameter(0.0, doc="all: a piece under this share of the mask's largest goes (specks beside the subject)",
                                 validator=between(0, 1))

    @property
    def postprocess(self) -> PostProcess:
        """The clean-up of this segmenter's raw masks."""
        return PostProcess(self.keep, self.dilation, self.bridge, self.min_piece)

    @abstractmethod
    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        """Yield (t, raw mask, labels or None) for every present frame of ``camera``, in order."""

    def segment(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        centre = rig_centre_in_view(session, camera) if self.keep == "central" else None
        for t, mask, labels in self.raw(session, camera):
            yield t, self.postprocess(mask, centre), labels


def rig_centre_in_view(session: SessionReader, camera: str) -> np.ndarray | None:
    """(u, v) where the rig's centre projects in ``camera``, or None where a rig has no centre (one camera,
    or parallel optical axes): its masks then keep their largest component."""
    try:
        return session.camera(camera).project(rig_center(session.cameras)[None])[0]
    except InputError:
        return None


def present_frames(session: SessionReader, camera: str) -> np.ndarray:
    """The frame indices ``camera`` has in ``session``, ascending."""
    return np.flatnonzero(session.present(camera))
