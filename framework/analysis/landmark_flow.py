"""Flow slip: how far a landmark's tracks have carried its image away from where the images moved it.

Where the tracks follow the images, a landmark's neighbourhood (the landmark and the centres of the
Gaussians that carry it, :func:`~mmcsplat.analysis.lost_landmarks.neighbourhoods`) moves in a camera's image
as the image itself moves: between frames t and t+1 each point's projection moves by what the session's
forward optical flow says at the pixel it starts from. The difference of the two, per image axis the median
over the points the camera images with confident flow (forward and backward flow agree there), is the
landmark's slip over that pair of frames; summed over the last :data:`WINDOW` pairs, it is how far its image
has slipped from theirs lately, in pixels. A window, not the sum from the run's first frame: the flow's small
errors would add up over a long run until every landmark, followed or not, had slipped. A leg the tracks leave behind
while the images show it swinging slips by the swing, though it may stay on the subject's masks (in front
of the other leg, or inside a loose mask). :mod:`mmcsplat.analysis.lost_landmarks` turns the slip into a
vote per camera.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mmcsplat.scene.camera import Camera
from mmcsplat.storage.session.flow import FlowPair, SessionFlow, pair_present

MIN_CONFIDENCE = 0.5  # forward–backward agreement below which a pixel's flow is an occlusion or noise
WINDOW = 10  # pairs of frames the slip is summed over: a limb left behind slips its swing within them, the flow's bias over a long run does not add up


def pair_slip(camera: Camera, before: np.ndarray, after: np.ndarray, flow: FlowPair, min_confidence: float = MIN_CONFIDENCE) -> np.ndarray:
    """[L, 2] px: each neighbourhood's slip in ``camera`` from one frame (``before`` [L, P, 3], NaN unused) to
    the next (``after``), against the camera's ``flow`` between them — the median over the points imaged
    with confident flow of their projected motion less the flow at their starting pixel; NaN where none is."""
    known = np.all(np.isfinite(before), axis=-1) & np.all(np.isfinite(after), axis=-1)
    start = np.where(known[..., None], before, 0.0).reshape(-1, 3)
    end = np.where(known[..., None], after, 0.0).reshape(-1, 3)
    pixels = camera.project(start)
    at = np.round(pixels).astype(int)
    depth = (start @ camera.R.T + camera.t)[:, 2]
    seen = known.ravel() & (depth > 0) & np.all((at >= 0) & (at < [camera.width, camera.height]), axis=1)
    seen[seen] = flow.forward_confidence[at[seen, 1], at[seen, 0]] >= min_confidence
    slips = np.full((len(start), 2), np.nan)
    slips[seen] = camera.project(end[seen]) - pixels[seen] - flow.forward[at[seen, 1], at[seen, 0]]
    slips = slips.reshape(*known.shape, 2)
    result = np.full((len(before), 2), np.nan)
    imaged = np.isfinite(slips[..., 0]).any(axis=1)
    result[imaged] = np.nanmedian(slips[imaged], axis=1)
    return result


def flow_slip(flow: SessionFlow, cameras: Sequence[Camera], frames: np.ndarray, points: np.ndarray, window: int = WINDOW,
              min_confidence: float = MIN_CONFIDENCE) -> np.ndarray:
    """[V, T, L] px: each landmark's slip in each camera with flow over the last ``window`` pairs of the session
    ``frames`` [T] (consecutive) up to each of them, summed, from its neighbourhood ``points`` [T, L, P, 3]
    there; NaN at the first frame and where the camera judged the landmark in none of those pairs. A pair a
    camera has no flow for, or does not image the landmark in with confident flow, adds nothing."""
    total = np.full((len(cameras), len(frames), points.shape[1]), np.nan)
    for v, camera in enumerate(cameras):
        pairs = pair_present(flow.present(camera.name))
        steps = np.full((len(frames), points.shape[1], 2), np.nan)  # steps[k]: the slip from frame k − 1 to frame k
        for k in range(1, len(frames)):
            if pairs[frames[k - 1]]:
                steps[k] = pair_slip(camera, points[k - 1], points[k], flow.pair(int(frames[k - 1]), camera.name), min_confidence)
            recent = steps[max(1, k - window + 1): k + 1]
            judged = np.isfinite(recent[..., 0]).any(axis=0)
            total[v, k, judged] = np.linalg.norm(np.nansum(recent[:, judged], axis=0), axis=1)
    return total


def slip_mm(slip: np.ndarray, cameras: Sequence[Camera], carried: np.ndarray) -> np.ndarray:
    """[V, T, L] mm: a :func:`flow_slip` in pixels as the distance it spans at the depth of each landmark
    ``carried`` [T, L, 3] (metres) in each camera — pixels × depth / focal length."""
    known = np.all(np.isfinite(carried), axis=-1)
    flat = np.where(known[..., None], carried, 0.0).reshape(-1, 3)
    scale = np.stack([((flat @ camera.R.T + camera.t)[:, 2] / float(camera.K[0, 0])).reshape(known.shape) for camera in cameras])
    return slip * np.where(known, scale, np.nan) * 1000.0
