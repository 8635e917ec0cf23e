"""Training views: a camera's frame loaded as loss targets, and the checks a frame's views must pass
(masks where the segmentation loss needs them, a subject some camera sees)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError, SubjectMaskError
from mmcsplat.plugin_api.interfaces import TrainingView

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import Initializer
    from mmcsplat.scene.camera import Camera
    from mmcsplat.storage.session import SessionReader

    from .settings import FitSettings

#: Fewer training cameras seeing the subject than this under-constrain a frame: the fit warns. On the
#: synthetic capture (64 × 48, visual-hull start, 1000 iterations) 4 training cameras left no opacity
#: outside the masks' visual hull and 3 left 10–16 % of it there (docs/studies.md, "Stability").
MIN_TRAINING_CAMERAS = 4


#: The images a monocular first fit trains on by default: the moving camera's next poses from the fitted
#: frame until it has taken this many (on the synthetic orbit, 8 frames: a quarter turn).
MONOCULAR_IMAGES = 8


def first_fit_images(session: SessionReader, cameras: Sequence[Camera], frame: int, window: int) -> list[tuple[int, int]]:
    """(session frame, training camera number) of every image a first fit trains on: the ``window`` frames
    from ``frame`` on when ``window`` > 0; otherwise the cameras that image ``frame`` when at least two
    training cameras do (a rig; one that missed that moment, as a Caliscope camera may, trains from the
    next frame on), else — one moving camera, a monocular capture — the frames from ``frame`` on until they
    hold :data:`MONOCULAR_IMAGES` images. An error when fewer than two images result."""
    present = np.stack([session.present(camera.name) for camera in cameras])  # [C, T]
    if window == 0 and present[:, frame].sum() >= 2:
        return [(frame, int(index)) for index in np.flatnonzero(present[:, frame])]
    stop = frame + window if window else frame
    if not window:
        while stop < present.shape[1] and present[:, frame:stop].sum() < MONOCULAR_IMAGES:
            stop += 1
    images = [(int(t), int(index)) for t in range(frame, min(stop, present.shape[1])) for index in np.flatnonzero(present[:, t])]
    if len(images) < 2:
        raise InputError(f"session {session.url}: frames {frame}–{stop - 1} hold {len(images)} training image(s); a fit needs at least "
                         "two: set fit.window to more frames, or fit.frame to a frame the cameras imaged")
    return images


def load_view(
    session: SessionReader, t: int, camera: Camera, index: int, initializers: Sequence[Initializer], backdrop: torch.Tensor
) -> TrainingView:
    """Frame ``t`` of ``camera`` (training camera number ``index``) as loss targets, shaped by the
    initializers' ``prepare_target``. They shape the image's difference from the ``backdrop``, so masking
    (which zeroes the outside of the subject) leaves the backdrop there: black, or the clean plate."""
    data = session.frame(t, camera.name)
    image = torch.from_numpy(data.rgb.astype(np.float32) / 255.0)
    mask = torch.from_numpy(data.mask.copy()) if data.mask is not None else None
    subject = image - backdrop
    for initializer in initializers:
        subject = initializer.prepare_target(subject, mask)
    seg = mask[..., None].float() if mask is not None else None
    return TrainingView(camera, index, subject + backdrop, mask, seg, backdrop)


def require_masks(views: Sequence[TrainingView], settings: FitSettings, session: SessionReader, t: int) -> None:
    """A segmentation loss (``lambda_seg`` > 0) needs every view's mask: an error naming the cameras that
    have none at frame ``t``."""
    missing = [view.camera.name for view in views if view.seg_target is None]
    if settings.lambda_seg > 0 and missing:
        raise InputError(
            f"fit.lambda_seg = {settings.lambda_seg} needs subject masks, but session {session.url!r} "
            f"has none for camera(s) {missing} at frame {t}: run `mmcsplat segment` or set fit.lambda_seg=0"
        )


def subject_warnings(views: Sequence[TrainingView], t: int) -> list[str]:
    """Warnings about how well frame ``t``'s views constrain the subject (each also issued with
    :func:`warnings.warn`); an error when no view's mask shows it at all."""
    masked = [view for view in views if view.mask is not None]
    if masked and not any(bool(view.mask.any()) for view in masked):
        raise SubjectMaskError(f"the subject mask is empty in every training view of frame {t}: check the segmentation")
    found = [f"camera {view.camera.name!r} never sees the subject at frame {t} (empty mask)" for view in masked if not view.mask.any()]
    seeing = sum(view.mask is None or bool(view.mask.any()) for view in views)
    if seeing < MIN_TRAINING_CAMERAS:
        found.insert(0, f"only {seeing} training cameras see the subject at frame {t}: it is under-constrained "
                        f"(expect floaters; at least {MIN_TRAINING_CAMERAS} are advised)")
    for warning in found:
        warnings.warn(warning, stacklevel=3)
    return found


def load_views(
    session: SessionReader,
    t: int,
    cameras: Sequence[Camera],
    initializers: Sequence[Initializer],
    backdrops: Sequence[torch.Tensor],
    settings: FitSettings,
) -> list[TrainingView]:
    """The views of session frame ``t`` whose camera holds that frame (absent ones skipped), camera
    ``cameras[i]`` as training camera ``i``; masks checked with :func:`require_masks`."""
    views = [
        load_view(session, t, camera, index, initializers, backdrops[index])
        for index, camera in enumerate(cameras)
        if session.present(camera.name)[t]
    ]
    require_masks(views, settings, session, t)
    return views
