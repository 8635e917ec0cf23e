"""Registers the built-in capture-format readers (through the ``mmcsplat`` entry points)."""

from __future__ import annotations

from mmcsplat import Registration, hookimpl


@hookimpl
def mmcsplat_readers() -> list[Registration]:
    return [
        Registration("videos", "mmcsplat.datasets.videos:VideoReader",
                     "per-camera videos in SOURCE/videos/ (Pose2Sim), SOURCE/videos-raw/ (anipose), SOURCE/synchronized_videos/ (FreeMoCap), "
                     "SOURCE/ or one folder per camera, with an anipose/Pose2Sim/Caliscope calibration .toml, a Qualisys .qca.txt or EasyMocap "
                     "intri.yml + extri.yml in SOURCE/ or SOURCE/calibration/ (a Pose2Sim batch trial: its session's calibration/), or OpenCap's "
                     "camera folders' pickles; an OpenCap session's Videos/CamN/InputMedia/TRIAL/TRIAL_sync.mp4"),
        Registration("images", "mmcsplat.datasets.images:ImageSequenceReader",
                     "per-camera folders of images (in SOURCE/ or SOURCE/images/) with a calibration .toml, a Qualisys .qca.txt or EasyMocap "
                     "intri.yml + extri.yml in SOURCE/ or SOURCE/calibration/"),
        Registration("d3dgs", "mmcsplat.datasets.d3dgs:D3DGSReader",
                     "Dynamic3DGaussians / CMU Panoptic (train_meta.json, ims/, seg/)"),
        Registration("dnerf", "mmcsplat.datasets.dnerf:DNeRFReader",
                     "D-NeRF / Blender (transforms_*.json, RGBA images; monocular)"),
        Registration("nerfstudio", "mmcsplat.datasets.nerfstudio:NerfstudioReader",
                     "nerfstudio (transforms.json: per-frame poses, intrinsics and OpenCV distortion)"),
        Registration("colmap", "mmcsplat.datasets.colmap:ColmapReader",
                     "a COLMAP sparse model (sparse/0/cameras, images: .bin or .txt) plus images/"),
    ]
