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

The masks miss a limb that stays on the subject's silhouette — a leg left behind in front of the other,
or inside a loose mask. Where the session has optical flow (``mmcsplat flow``), a frame also holds the
landmark off when its neighbourhood's image has slipped from the images' motion over the last
:data:`~mmcsplat.analysis.landmark_flow.WINDOW` pairs of frames (:mod:`mmcsplat.analysis.landmark_flow`) by more than :data:`SLIP_MM` at the landmark's depth, and
:data:`MIN_SLIP_PX` at least (flow's noise on small images), in at least :data:`VIEW_FRACTION` of the
cameras with flow that image it (:data:`MIN_VIEWS` at least). Measured against the Pose2Sim demo's
triangulated joints (docs/landmarks.md), the masks alone are precise but catch few lost landmarks; the
slip catches nearly three times as many, at the price of false alarms that grow as the tracks get better.
"""

from __future__ import annotations

from collections.abc import Sequence

import attrs
import numpy as np

from mmcsplat.analysis.landmark_flow import MIN_CONFIDENCE, WINDOW, flow_slip, slip_mm
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.session.flow import SessionFlow

TOLERANCE = 0.015  # of the image diagonal: 8 px at 270 × 480, 4 px at 135 × 240
MIN_TOLERANCE_PX = 2.0
VIEW_FRACTION = 0.5
MIN_VIEWS = 2
CONSECUTIVE = 3
SLIP_MM = 50.0  # the slip from the flow, at the landmark's depth, beyond which a camera finds it off
MIN_SLIP_PX = 2.0

#: A view: a camera and its [H, W] float32 distance (px) to the subject mask (0 on it).
DistanceView = tuple[Camera, np.ndarray]
#: What a line says when the session had no optical flow to judge slips by.
NO_FLOW = " — masks only: `mmcsplat flow SESSION` adds the flow check"


@attrs.frozen
class LostRule:
    """The thresholds of the module docstring's rule, recorded beside what it found."""

    tolerance: float = TOLERANCE
    min_tolerance_px: float = MIN_TOLERANCE_PX
    view_fraction: float = VIEW_FRACTION
    min_views: int = MIN_VIEWS
    consecutive: int = CONSECUTIVE
    slip_mm: float = SLIP_MM
    slip_window: int = WINDOW
    min_slip_px: float = MIN_SLIP_PX
    min_flow_confidence: float = MIN_CONFIDENCE

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
    mask over the points in front of the view; NaN where fewer than half of them are. A point beyond the
    image's edge is at least as far from the mask (which lies inside the image) as from the edge, and at
    least its edge pixel's distance less that: the larger bound counts, so a landmark carried out of every
    image is judged, not left unjudged."""
    known = np.all(np.isfinite(points), axis=-1)
    flat = np.where(known[..., None], points, 0.0).reshape(-1, 3)
    result = np.full((len(views), len(points)), np.nan)
    for v, (camera, distance) in enumerate(views):
        depth = (flat @ camera.R.T + camera.t)[:, 2]
        seen = known.ravel() & (depth > 0)
        pixels = np.zeros((len(flat), 2))
        pixels[seen] = camera.project(flat[seen])
        edge = np.clip(np.round(pixels), 0, [camera.width - 1, camera.height - 1]).astype(int)
        beyond = np.hypot(*(pixels - np.clip(pixels, -0.5, [camera.width - 0.5, camera.height - 0.5])).T)
        values = np.full(len(flat), np.nan)
        at_edge = distance[edge[seen, 1], edge[seen, 0]]
        values[seen] = np.where(beyond[seen] > 0, np.maximum(beyond[seen], at_edge - beyond[seen]), at_edge)
        values = values.reshape(known.shape)
        imaged = np.isfinite(values).sum(axis=1)
        enough = (imaged > 0) & (2 * imaged >= known.sum(axis=1))
        result[v, enough] = np.nanmedian(values[enough], axis=1)
    return result


def voted(off: np.ndarray, imaged: np.ndarray, rule: LostRule) -> np.ndarray:
    """[...] bool: where at least the rule's share of the views that image a landmark (``imaged`` [V, ...]),
    and its fewest views at least, find it ``off`` [V, ...]."""
    seen = imaged.sum(axis=0)
    return (seen >= rule.min_views) & ((off & imaged).sum(axis=0) >= rule.view_fraction * seen)


def off_subject(distances: np.ndarray, tolerances: np.ndarray, rule: LostRule) -> np.ndarray:
    """[L] bool: landmarks off the subject at one frame, from their ``distances`` [V, L] (NaN where the
    view does not image them) and the views' ``tolerances`` [V] px."""
    imaged = np.isfinite(distances)
    return voted(np.where(imaged, distances, 0.0) > np.asarray(tolerances, dtype=float)[:, None], imaged, rule)


def slipped(session: SessionReader, cameras: Sequence[str], frames: np.ndarray, points: np.ndarray, carried: np.ndarray,
            rule: LostRule) -> np.ndarray | None:
    """[T, L] bool: the frames where the landmarks' images slipped from the session's optical flow in most
    of the training ``cameras`` with flow (module docstring), from their neighbourhoods ``points``
    [T, L, P, 3] and positions ``carried`` [T, L, 3] at the session ``frames`` [T]; ``None`` when the
    session has no flow for any of them."""
    flow = SessionFlow(session.url)
    with_flow = [session.camera(name) for name in cameras if flow.available and flow.has(name)]
    if not with_flow:
        return None
    pixels = flow_slip(flow, with_flow, frames, points, rule.slip_window, rule.min_flow_confidence)
    judged = np.isfinite(pixels)
    far = (np.where(judged, slip_mm(pixels, with_flow, carried), 0.0) > rule.slip_mm) & (np.where(judged, pixels, 0.0) > rule.min_slip_px)
    return voted(far, judged, rule)


def off_at_frame(session: SessionReader, cameras: Sequence[str], frame: int, points: np.ndarray, rule: LostRule) -> np.ndarray | None:
    """[L] bool: the landmarks off the subject at session ``frame``, their neighbourhoods at ``points``
    [L, P, 3] (:func:`neighbourhoods`), judged on the masks of the training ``cameras`` holding the frame;
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
    return off_subject(view_distances(points, views), np.array(tolerances), rule)


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
                rule: LostRule, tolerances: dict[str, float], slips: np.ndarray | None = None) -> dict[str, object]:
    """landmarks.json's ``lost`` entry: the rule, each camera's tolerance (px), how many frames had a mask
    to judge by, whether the optical flow judged too (``slips`` [T, L], ``None`` without flow), and per bound
    landmark its ``first_lost_frame`` (None when never lost), ``lost_frames`` (session frame numbers) and
    ``found_by`` (``masks``, ``flow``: which signals held it off in those frames), from ``off`` [T, L] (off the
    masks) at session ``frames`` [T]."""
    flow_judged = slips is not None
    slips = np.zeros_like(off) if slips is None else slips
    lost = lost_frames(off | slips, rule.consecutive)
    landmarks = {}
    for j, name in enumerate(names):
        if bound[j]:
            indices = frames[lost[:, j]].tolist()
            found_by = [signal for signal, fired in (("masks", off), ("flow", slips)) if (fired[:, j] & lost[:, j]).any()]
            landmarks[name] = {"first_lost_frame": indices[0] if indices else None, "lost_frames": indices, "found_by": found_by}
    return {"rule": attrs.asdict(rule), "tolerance_px": tolerances, "frames_judged": int(judged.sum()),
            "flow_judged": flow_judged, "landmarks": landmarks}


def lost_names(record: dict[str, object]) -> dict[str, dict[str, object]]:
    """The landmarks of a ``lost`` record that were lost, each with its first lost frame and lost frames."""
    return {name: entry for name, entry in record["landmarks"].items() if entry["first_lost_frame"] is not None}


def lost_line(record: dict[str, object]) -> str:
    """One line naming the lost landmarks of a ``lost`` record, the frames from which they were lost and
    the signals that found them."""
    lost = lost_names(record)
    flow = record.get("flow_judged", False)
    if not record["frames_judged"] and not flow:
        return "lost landmarks not judged: the session has neither subject masks nor optical flow for the run's training cameras"
    if not lost:
        checks = f"the subject masks ({record['frames_judged']} frames judged)" + (" and the optical flow" if flow else "")
        return f"no landmark lost: every carried landmark followed {checks}" + ("" if flow else NO_FLOW)
    ordered = sorted(lost.items(), key=lambda item: (item[1]["first_lost_frame"], item[0]))
    return "lost (off the subject masks or slipped from the optical flow in most cameras): " + ", ".join(
        f"{name} from frame {entry['first_lost_frame']} ({len(entry['lost_frames'])} frames; {', '.join(entry.get('found_by', ['masks']))})"
        for name, entry in ordered) + ("" if flow else NO_FLOW)
