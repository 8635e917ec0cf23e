"""Lost landmarks: where a run's tracks stopped following the images, per landmark and frame.

A subject's point lies inside its silhouette in every camera that images it, so a carried landmark whose
tracks follow the subject projects onto each training camera's subject mask. At each frame the landmark's
*neighbourhood* — the landmark and the centres of the Gaussians that carry it — is projected into every
training camera with a mask there; the camera's distance for the landmark is the median over the
neighbourhood points it images of each point's distance (px) to the nearest mask pixel (0 on the mask),
so one anchor at the silhouette's edge does not decide. The camera finds the landmark *off* when that
distance exceeds :data:`TOLERANCE` of the image's diagonal, at least :data:`MIN_TOLERANCE_PX` — a mask's
edge errors and a joint centre near a thin limb's edge stay within it, a limb left behind by its own
width does not. A frame holds the landmark off when at least :data:`VIEW_FRACTION` of the cameras that
image it (and :data:`MIN_VIEWS` at least) find it off: one wrong mask is outvoted. The landmark is
*lost* over every run of at least :data:`CONSECUTIVE` frames off; shorter runs are a mask's noise.
"""

from __future__ import annotations

from collections.abc import Sequence

import attrs
import numpy as np

from mmcsplat.scene.camera import Camera
from mmcsplat.scene.landmark_anchors import LandmarkBinding
from mmcsplat.storage.session import SessionReader

TOLERANCE = 0.015  # of the image diagonal: 8 px at 270 × 480, 4 px at 135 × 240
MIN_TOLERANCE_PX = 2.0
VIEW_FRACTION = 0.5
MIN_VIEWS = 2
CONSECUTIVE = 3

#: A view: a camera and its [H, W] float32 distance (px) to the subject mask (0 on it).
DistanceView = tuple[Camera, np.ndarray]


@attrs.frozen
class LostRule:
    """The thresholds of the module docstring's rule, recorded beside what it found."""

    tolerance: float = TOLERANCE
    min_tolerance_px: float = MIN_TOLERANCE_PX
    view_fraction: float = VIEW_FRACTION
    min_views: int = MIN_VIEWS
    consecutive: int = CONSECUTIVE

    def tolerance_px(self, camera: Camera) -> float:
        """The distance (px) from ``camera``'s mask beyond which it finds a landmark off."""
        return max(self.min_tolerance_px, self.tolerance * float(np.hypot(camera.width, camera.height)))


def mask_distance(mask: np.ndarray) -> np.ndarray | None:
    """[H, W] float32: each pixel's distance (px) to the nearest pixel of the bool ``mask`` (0 on it);
    ``None`` for an empty mask, which says nothing about where the subject is."""
    import cv2

    if not mask.any():
        return None
    return cv2.distanceTransform(np.where(mask, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def neighbourhoods(carried: np.ndarray, anchors: np.ndarray, weights: np.ndarray, means: np.ndarray) -> np.ndarray:
    """[L, 1 + k, 3]: each landmark of ``carried`` [L, 3] and the centres ``means`` [N, 3] of its
    ``anchors`` [L, k] at one frame; NaN where an anchor slot is unused (weight 0) or the landmark unknown."""
    points = np.concatenate([carried[:, None], means[anchors]], axis=1)
    points[:, 1:][weights <= 0] = np.nan
    points[~np.all(np.isfinite(carried), axis=1)] = np.nan
    return points


def view_distances(points: np.ndarray, views: Sequence[DistanceView]) -> np.ndarray:
    """[V, L] px: per view, each neighbourhood's (``points`` [L, P, 3], NaN unused) median distance to the
    mask over the points the view images (in front of it, inside its image); NaN where it images fewer
    than half of them."""
    known = np.all(np.isfinite(points), axis=-1)
    flat = np.where(known[..., None], points, 0.0).reshape(-1, 3)
    result = np.full((len(views), len(points)), np.nan)
    for v, (camera, distance) in enumerate(views):
        depth = (flat @ camera.R.T + camera.t)[:, 2]
        pixels = np.round(camera.project(flat)).astype(int)
        seen = known.ravel() & (depth > 0) & np.all((pixels >= 0) & (pixels < [camera.width, camera.height]), axis=1)
        values = np.full(len(flat), np.nan)
        values[seen] = distance[pixels[seen, 1], pixels[seen, 0]]
        values = values.reshape(known.shape)
        imaged = np.isfinite(values).sum(axis=1)
        enough = (imaged > 0) & (2 * imaged >= known.sum(axis=1))
        result[v, enough] = np.nanmedian(values[enough], axis=1)
    return result


def off_subject(distances: np.ndarray, tolerances: np.ndarray, rule: LostRule) -> np.ndarray:
    """[L] bool: landmarks off the subject at one frame, from their ``distances`` [V, L] (NaN where the
    view does not image them) and the views' ``tolerances`` [V] px."""
    imaged = np.isfinite(distances)
    off = (np.where(imaged, distances, 0.0) > np.asarray(tolerances, dtype=float)[:, None]).sum(axis=0)
    seen = imaged.sum(axis=0)
    return (seen >= rule.min_views) & (off >= rule.view_fraction * seen)


def off_at_frame(session: SessionReader, cameras: Sequence[str], frame: int, binding: LandmarkBinding, carried: np.ndarray,
                 means: np.ndarray, rule: LostRule) -> np.ndarray | None:
    """[L] bool: the landmarks off the subject at session ``frame``, where they are ``carried`` [L, 3] by
    Gaussians at ``means`` [N, 3], judged on the masks of the training ``cameras`` holding the frame;
    ``None`` when none has a non-empty mask there."""
    views, tolerances = [], []
    for name in cameras:
        data = session.frame(frame, name) if session.present(name)[frame] else None
        distance = mask_distance(data.mask) if data is not None and data.mask is not None else None
        if distance is not None:
            camera = session.camera(name)
            views.append((camera, distance))
            tolerances.append(rule.tolerance_px(camera))
    if not views:
        return None
    return off_subject(view_distances(neighbourhoods(carried, binding.anchors, binding.weights, means), views), np.array(tolerances), rule)


def lost_frames(off: np.ndarray, consecutive: int = CONSECUTIVE) -> np.ndarray:
    """[T, L] bool: the frames of ``off`` [T, L] that belong to a run of at least ``consecutive`` off frames."""
    lost = np.zeros_like(off, dtype=bool)
    for j in range(off.shape[1]):
        start = None
        for k, value in enumerate([*off[:, j], False]):
            if value and start is None:
                start = k
            elif not value and start is not None:
                if k - start >= consecutive:
                    lost[start:k, j] = True
                start = None
    return lost


def lost_record(names: Sequence[str], bound: np.ndarray, frames: np.ndarray, off: np.ndarray, judged: np.ndarray,
                rule: LostRule, tolerances: dict[str, float]) -> dict[str, object]:
    """landmarks.json's ``lost`` entry: the rule, each camera's tolerance (px), how many frames had a mask
    to judge by, and per bound landmark its ``first_lost_frame`` (None when never lost) and
    ``lost_frames`` (session frame numbers), from ``off`` [T, L] at session ``frames`` [T]."""
    lost = lost_frames(off, rule.consecutive)
    landmarks = {}
    for j, name in enumerate(names):
        if bound[j]:
            indices = frames[lost[:, j]].tolist()
            landmarks[name] = {"first_lost_frame": indices[0] if indices else None, "lost_frames": indices}
    return {"rule": attrs.asdict(rule), "tolerance_px": tolerances, "frames_judged": int(judged.sum()), "landmarks": landmarks}


def lost_names(record: dict[str, object]) -> dict[str, dict[str, object]]:
    """The landmarks of a ``lost`` record that were lost, each with its first lost frame and lost frames."""
    return {name: entry for name, entry in record["landmarks"].items() if entry["first_lost_frame"] is not None}


def lost_line(record: dict[str, object]) -> str:
    """One line naming the lost landmarks of a ``lost`` record and the frames from which they were lost."""
    lost = lost_names(record)
    if not record["frames_judged"]:
        return "lost landmarks not judged: the session has no subject masks for the run's training cameras"
    if not lost:
        return f"no landmark lost: every carried landmark stayed on the subject masks ({record['frames_judged']} frames judged)"
    ordered = sorted(lost.items(), key=lambda item: (item[1]["first_lost_frame"], item[0]))
    return "lost (off the subject masks in most cameras): " + ", ".join(
        f"{name} from frame {entry['first_lost_frame']} ({len(entry['lost_frames'])} frames)" for name, entry in ordered)
