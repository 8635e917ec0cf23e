"""How the built-in synthetic capture is ingested when nothing else is said — by ``mmcsplat demo`` and by a
study's synthetic sessions alike: the camera held out, and the segmenter (the masks the capture ships,
their central component kept per view)."""

from __future__ import annotations

SYNTHETIC_SEGMENTER = "precomputed"
SYNTHETIC_HELDOUT = ("cam_0",)
