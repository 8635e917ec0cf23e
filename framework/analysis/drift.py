"""Drift detection: foreground Gaussians of a dynamic run that leave the subject (the floaters the
iterative method is known for).

At every tracked frame, each foreground Gaussian's centre (segmentation colour > 0.5) is projected into
every training view holding that frame. A view *sees* it when the centre is in front of the camera and
inside the image; it is *outside* in that view when it falls off the subject mask dilated by
``margin_px`` pixels (the mask's own edge errors are not drift). A Gaussian has left the subject when it
is outside in at least ``view_fraction`` of the views that see it — the mask hull across views.

The run drifts when, at some frame, the share of foreground Gaussians off the subject exceeds the first
frame's share by more than ``max_fraction`` (default 2 %: the first frame's fit already has a few at the
mask's edge, and a good run stays within about 1 % of it; see docs/performance.md "Dynamics").
"""

from __future__ import annotations

from collections.abc import Sequence

import attrs
import numpy as np

from mmcsplat.analysis.visual_hull import dilated
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.visual_hull import mask_votes
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader

VIEW_FRACTION = 0.5
MARGIN_PX = 2
MAX_FRACTION = 0.02
FOREGROUND = 0.5


@attrs.frozen
class DriftReport:
    """Per tracked frame (session frames ``first_frame``…), how many foreground Gaussians are off the
    subject (``counts``) and as a share of the ``foreground`` count (``fractions``); ``drifted`` lists the
    Gaussians (indices into the tracks) off the subject at some frame but not at the first; ``drift`` says
    whether the run drifts; the thresholds it was judged with."""

    counts: list[int]
    fractions: list[float]
    foreground: int
    drifted: list[int]
    drift: bool
    view_fraction: float
    margin_px: int
    max_fraction: float
    first_frame: int = 0

    @property
    def since(self) -> int | None:
        """The first session frame whose share off the subject exceeds the first frame's by more than
        ``max_fraction`` (``None`` when the run does not drift)."""
        over = [k for k, fraction in enumerate(self.fractions) if fraction - self.fractions[0] > self.max_fraction]
        return self.first_frame + over[0] if over else None

    def explain(self) -> str:
        """The verdict in one line: how many Gaussians left the subject, since which frame, at most how many at once."""
        worst = int(np.argmax(self.counts))
        peak = (f"at most {self.counts[worst]} at once (frame {self.first_frame + worst}, {self.fractions[worst]:.1%}; "
                f"{self.counts[0]} at the first frame)")
        if self.since is None:
            return (f"no drift: {len(self.drifted)} of {self.foreground} foreground Gaussians left the subject at some frame, {peak}, "
                    f"within the first frame's share + {self.max_fraction:.0%}")
        return (f"drift: {len(self.drifted)} of {self.foreground} foreground Gaussians left the subject, more than the first frame's "
                f"share + {self.max_fraction:.0%} since frame {self.since}; {peak}")


def off_subject(points: np.ndarray, views: Sequence[tuple[Camera, np.ndarray]], view_fraction: float = VIEW_FRACTION) -> np.ndarray:
    """[N] bool: ``points`` [N, 3] outside the (camera, mask) ``views``' masks in at least
    ``view_fraction`` of the views that see them (never for points no view sees)."""
    seen, inside = mask_votes(points, views)
    outside = seen - inside
    return (seen > 0) & (outside >= view_fraction * seen)


def detect_drift(
    tracks: TrackReader,
    session: SessionReader,
    cameras: Sequence[str],
    *,
    view_fraction: float = VIEW_FRACTION,
    margin_px: int = MARGIN_PX,
    max_fraction: float = MAX_FRACTION,
    foreground: float = FOREGROUND,
) -> DriftReport:
    """Judge ``tracks`` against the masks of the training ``cameras`` of ``session`` (module docstring)."""
    first_frame = int(tracks.attrs.get("first_frame", 0))
    seg = 1 / (1 + np.exp(-tracks.params(0)["seg_logits"].numpy()[:, 0]))
    index = np.flatnonzero(seg > foreground)
    if not len(index):
        raise InputError(f"{tracks.path}: no foreground Gaussians (segmentation colour > {foreground}) to check for drift")
    counts, ever = [], np.zeros(len(index), dtype=bool)
    at_first = None
    for k in range(tracks.num_frames):
        t = first_frame + k
        views = []
        for name in cameras:
            if session.present(name)[t]:
                mask = session.frame(t, name).mask
                if mask is None:
                    raise InputError(f"drift detection needs subject masks: session {session.url!r} has none for camera {name!r} at frame {t}")
                views.append((session.camera(name), dilated(mask, margin_px)))
        off = off_subject(tracks.means(k)[index].astype(np.float64), views, view_fraction)
        at_first = off if at_first is None else at_first
        ever |= off & ~at_first
        counts.append(int(off.sum()))
    fractions = [count / len(index) for count in counts]
    return DriftReport(
        counts=counts,
        fractions=fractions,
        foreground=len(index),
        drifted=index[ever].tolist(),
        drift=bool(max(fractions) - fractions[0] > max_fraction),
        view_fraction=view_fraction,
        margin_px=margin_px,
        max_fraction=max_fraction,
        first_frame=first_frame,
    )
