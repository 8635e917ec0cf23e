"""What evaluation scores: a camera's view of a run's Gaussians over that camera's backdrop, inside the
mask it is scored in — the session's, or for a held-out camera without one the training cameras' visual
hull as it projects there — and the held-out cameras' scores at every tracked frame."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
import torch

from mmcsplat.analysis.visual_hull import projected_hull_mask
from mmcsplat.plugin_api.render_contract import RenderCameras, composite

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import Renderer
    from mmcsplat.plugin_api.render_contract import Gaussians
    from mmcsplat.scene.camera import Camera
    from mmcsplat.storage.session import SessionReader
    from mmcsplat.storage.tracks import TrackReader

#: Where a view's scoring mask came from (``per_camera[…]["mask"]`` in metrics.json).
SESSION_MASK = "session"
HULL_MASK = "hull of the training cameras' masks"
#: A hull mask covering more than this share of the held-out image is not scored as a subject mask. It
#: leaves out less than a fifth of the image, so where the background is reproduced well the "masked"
#: PSNR is within 10·log10(1 / 0.8) ≈ 1 dB of the full-image PSNR: it measures the image, not the subject
#: (a hull that wide comes from masks far larger than the subject, or a camera close to it).
HULL_COVERAGE_LIMIT = 0.8


@attrs.frozen(eq=False)  # holds an array: compared by identity
class ScoringMask:
    """The mask a view is scored in: ``mask`` ([H, W] bool; ``None``: full-image scores only), where it
    came from (``source``), the hull mask's share of the image (``coverage``, ``None`` for a session
    mask) and, without a mask, why (``reason``)."""

    mask: np.ndarray | None
    source: str | None = None
    coverage: float | None = None
    reason: str | None = None


def render_over(renderer: Renderer, gaussians: Gaussians, camera: Camera, backdrop: torch.Tensor) -> torch.Tensor:
    """``camera``'s view of ``gaussians`` over ``backdrop`` ([H, W, 3], no gradients): what evaluation scores."""
    with torch.no_grad():
        return composite(renderer.render(gaussians, RenderCameras.from_cameras([camera])), 0, backdrop)


def training_masks(session: SessionReader, frame: int, cameras: Sequence[str]) -> list[tuple[Camera, np.ndarray]]:
    """(camera, mask) of each of ``cameras`` holding ``frame`` with a mask there."""
    views = []
    for name in cameras:
        mask = session.frame(frame, name).mask if session.present(name)[frame] else None
        if mask is not None:
            views.append((session.camera(name), mask))
    return views


def heldout_mask(session_mask: np.ndarray | None, camera: Camera, frame: int, train_views: Sequence[tuple[Camera, np.ndarray]],
                 center: np.ndarray, radius: float) -> ScoringMask:
    """The mask held-out ``camera`` is scored in at ``frame``: its own ``session_mask``, else the hull of the
    training ``train_views``' masks projected into it (inside the sphere of ``radius`` about ``center``) —
    unless that hull covers more than :data:`HULL_COVERAGE_LIMIT` of the image or fewer than two
    training cameras have masks, when it is scored on the full image only and ``reason`` says why."""
    if session_mask is not None:
        return ScoringMask(session_mask, SESSION_MASK)
    if len(train_views) < 2:
        return ScoringMask(None, reason=f"no mask of its own and {len(train_views)} training camera(s) with a mask at frame {frame} "
                                        "(a hull needs two): scored on the full image only")
    mask = projected_hull_mask(camera, train_views, center, radius)
    coverage = float(mask.mean())
    if coverage > HULL_COVERAGE_LIMIT:
        return ScoringMask(None, coverage=coverage, reason=(
            f"the training cameras' hull covers {coverage:.0%} of its image at frame {frame} (more than {HULL_COVERAGE_LIMIT:.0%}): "
            "a masked PSNR would measure the image, not the subject, so it is scored on the full image only — give it a mask "
            "(`mmcsplat segment`) or check the training masks"))
    return ScoringMask(mask, HULL_MASK, coverage)


def tracked_heldout_scores(tracks: TrackReader, session: SessionReader, heldout: Sequence[str], train_cameras: Sequence[str],
                           renderer: Renderer, psnr: Callable[..., float], backdrops: dict[str, torch.Tensor], center: np.ndarray,
                           radius: float, progress: bool = False) -> dict[str, Any]:
    """The held-out cameras' scores at every tracked frame, each in its :func:`heldout_mask` of that frame:
    ``per_frame_val_psnr`` and ``per_frame_val_masked_psnr`` (their mean per frame, ``None`` at a frame no
    held-out camera imaged or could be scored masked at), ``tracked_val_psnr`` and ``tracked_val_masked_psnr``
    (means over the scored frames), and ``tracked_val_unmasked``: per held-out camera left unmasked at some
    frame, at how many frames and why (the first frame's reason). ``progress`` shows a bar over the frames."""
    from tqdm import tqdm

    first = int(tracks.attrs.get("first_frame", 0))
    full, masked, unmasked = [], [], {}
    for k in tqdm(range(tracks.num_frames), desc="evaluate: tracked frames", unit="frame", disable=not progress):
        t = first + k
        gaussians = tracks.gaussians(k)
        names = [name for name in heldout if session.present(name)[t]]
        train_views = training_masks(session, t, train_cameras) if names else []
        full_scores, masked_scores = [], []
        for name in names:
            data, camera = session.frame(t, name), session.camera(name)
            rgb = render_over(renderer, gaussians, camera, backdrops[name])
            prediction, target = rgb.clamp(0, 1).double().numpy(), data.rgb.astype(np.float64) / 255.0
            full_scores.append(psnr(prediction, target))
            scoring = heldout_mask(data.mask, camera, t, train_views, center, radius)
            if scoring.mask is not None and scoring.mask.any():
                masked_scores.append(psnr(prediction, target, scoring.mask))
            else:
                entry = unmasked.setdefault(name, {"frames": 0, "reason": scoring.reason or f"its mask is empty at frame {t}"})
                entry["frames"] += 1
        full.append(float(np.mean(full_scores)) if full_scores else None)
        masked.append(float(np.mean(masked_scores)) if masked_scores else None)
    return {
        "per_frame_val_psnr": full,
        "per_frame_val_masked_psnr": masked,
        "tracked_val_psnr": _mean_of_scored(full),
        "tracked_val_masked_psnr": _mean_of_scored(masked),
        "tracked_val_unmasked": unmasked,
    }


def _mean_of_scored(values: list[float | None]) -> float | None:
    scored = [value for value in values if value is not None]
    return float(np.mean(scored)) if scored else None
