"""The built-in synthetic infant capture: an analytic ray-cast scene with ground truth.

``synthesize(out_dir, SynthConfig(...))`` renders an infant-sized articulated body lying supine on a
textured mat, moving spontaneously, seen by a ring of distorted cameras, and writes what a real rig
writes (``videos/<camera>.mp4``, an anipose ``calibration.toml``) plus the ground truth a real rig lacks
(``ground_truth.zarr``: masks, depth, labelled surface points and joints over time), which
:class:`SynthGroundTruth` reads back. Modules: :mod:`.body` (parts and kinematics), :mod:`.motion`,
:mod:`.textures`, :mod:`.cameras`, :mod:`.raycast`, :mod:`.scene` (rendering one view), :mod:`.writer`;
:mod:`.defaults` says how the capture is ingested when nothing else is said (demo, studies).
"""

from mmcsplat.synthetic.ground_truth import SynthGroundTruth
from mmcsplat.synthetic.synthesize import SynthConfig, SynthResult, synthesize

__all__ = ["SynthConfig", "SynthGroundTruth", "SynthResult", "synthesize"]
