"""The table of per-Gaussian parameters: their names and shapes, as the model trains them and tracks
store them. Colours and the segmentation colour are logits, scales are logarithms, opacities logits."""

from __future__ import annotations

#: Trailing shape of each per-Gaussian parameter ([N, *shape]), in the order models and tracks list them.
PARAMETER_SHAPES: dict[str, tuple[int, ...]] = {
    "means": (3,),
    "quats": (4,),
    "log_scales": (3,),
    "opacity_logits": (),
    "color_logits": (3,),
    "seg_logits": (1,),
}
#: Per-Gaussian parameter tensors, first dimension N.
GAUSSIAN_PARAMETERS: tuple[str, ...] = tuple(PARAMETER_SHAPES)
