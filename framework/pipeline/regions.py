"""Start and pruning regions sized to the subject: the shipped configurations start Gaussians in a cube
sized for an infant on a mat (half side 0.75 m) and prune beyond 2 m; a standing adult, or two players
1.5 m from the rig's centre, do not fit in them. Before a fit, the subject's visual hull (from the training
cameras' masks at the fitted frame) gives how far it reaches from the rig's centre, and every
``half_size`` and ``radius`` that its initializer would refuse as too small is grown — never shrunk, so a
fit that already holds its subject runs exactly as configured (the demo's infant; the study's rows).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mmcsplat.configuration.config import Config
from mmcsplat.configuration.registry import default_registry
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.settings import FitSettings

#: Metres added to the hull's reach for a grown region.
REGION_MARGIN = 0.1


def hull_offsets(session: SessionReader, holdout: Sequence[str] | None, frame: int) -> np.ndarray | None:
    """[K, 3] the subject's visual hull cells less the rig centre, from the masks of the training cameras
    imaging ``frame``; ``None`` with fewer than two such masks, an empty hull, or no such frame."""
    from mmcsplat.pipeline.fit import select_cameras
    from mmcsplat.scene.rig import rig_center, rig_scale
    from mmcsplat.scene.visual_hull import hull_cells

    if not 0 <= frame < session.num_frames:  # the fit itself refuses it, naming the session's frames
        return None
    train, _ = select_cameras(session, holdout)
    views = [(camera, session.frame(frame, camera.name).mask) for camera in train if session.present(camera.name)[frame]]
    views = [(camera, mask) for camera, mask in views if mask is not None]
    if len(views) < 2:
        return None
    center = rig_center(session.cameras)
    cells = hull_cells(views, center, rig_scale(session.cameras, center)) - center
    return cells if len(cells) else None


def region_overrides(session: SessionReader, config: Config, holdout: Sequence[str] | None = None) -> list[str]:
    """``--set`` overrides growing each ``[[initializer]]``'s ``half_size`` (start cube) or ``radius``
    (pruning sphere) that holds less than :data:`~mmcsplat.scene.visual_hull.REGION_SHARE` of the subject's
    visual hull — the regions its initializer would refuse — to the hull's reach plus :data:`REGION_MARGIN`,
    rounded up to 0.1 m; empty when the masks give no hull or every region holds it."""
    from mmcsplat.scene.visual_hull import REGION_SHARE, region_reach

    offsets = hull_offsets(session, holdout, FitSettings.from_config(config).frame)
    if offsets is None:
        return []
    reaches = {"half_size": region_reach(offsets, cube=True), "radius": region_reach(offsets, cube=False)}
    overrides = []
    registry = default_registry()
    for index, choice in enumerate(config.plugins("initializer")):
        initializer = choice.build(registry)  # its values in force, defaults included
        for key, reach in reaches.items():
            current = getattr(initializer, key, None)
            if isinstance(current, float) and np.mean(reach <= current) < REGION_SHARE:
                needed = np.ceil((reach.max() + REGION_MARGIN) * 10) / 10
                overrides.append(f"initializer.{index}.{key}={float(needed)}")
    return overrides
