"""Registers the built-in segmenters, initializers, depth sources, densifiers, dynamics methods and metrics."""

from __future__ import annotations

from mmcsplat import Registration, hookimpl, needs_modules


@hookimpl
def mmcsplat_initializers() -> list[Registration]:
    return [
        Registration("random", "mmcsplat.plugins.initializers:RandomInitializer",
                     "N Gaussians uniform in a cube around the calibration centre"),
        Registration("masked", "mmcsplat.plugins.initializers:MaskedInitializer",
                     "fit shaper: images zeroed outside the subject mask; Gaussians far from the centre pruned"),
        Registration("visual-hull", "mmcsplat.plugins.initializers:VisualHullInitializer",
                     "Gaussians sampled inside the intersection of the cameras' mask cones"),
        Registration("depth-supervised", "mmcsplat.plugins.initializers:DepthSupervisedInitializer",
                     "fit shaper: L1 depth loss with a learnable per-camera scale and offset"),
        Registration("sparsity-pruned", "mmcsplat.plugins.initializers:SparsityPrunedInitializer",
                     "fit shaper: prune Gaussians whose nearest neighbour is farther than 0.1 m"),
        Registration("in-view", "mmcsplat.plugins.initializers:InViewInitializer",
                     "fit shaper: prune Gaussians that no training camera sees (they never get a gradient)"),
    ]


@hookimpl
def mmcsplat_densifiers() -> list[Registration]:
    return [
        Registration("default", "mmcsplat.plugins.densifiers:DefaultDensifier",
                     "3DGS clone/split on the screen-space gradient, opacity and size pruning"),
        Registration("budget", "mmcsplat.plugins.densifiers:BudgetDensifier",
                     "a hard cap on the Gaussian count; dead Gaussians relocated (MCMC-style)"),
    ]


@hookimpl
def mmcsplat_dynamics() -> list[Registration]:
    return [
        Registration("iterative", "mmcsplat.plugins.dynamics.iterative:IterativeDynamics",
                     "per-frame optimisation from the previous frame with local-rigidity priors (Luiten et al.)"),
        Registration("deformation", "mmcsplat.plugins.dynamics.deformation:DeformationDynamics",
                     "one MLP deformation field over (x, y, z, t) for the whole sequence (Yang et al.)"),
    ]


@hookimpl
def mmcsplat_depth_sources() -> list[Registration]:
    return [
        Registration("session", "mmcsplat.plugins.depth_sources:SessionDepth",
                     "the session's depth field (synthetic ground truth, a depth camera), optionally with noise"),
    ]


@hookimpl
def mmcsplat_metrics() -> list[Registration]:
    return [
        Registration("psnr", "mmcsplat.plugins.metrics:PSNR", "peak signal-to-noise ratio (dB), optionally inside a mask"),
        Registration("ssim", "mmcsplat.plugins.metrics:SSIM", "structural similarity, optionally inside a mask"),
    ]


@hookimpl
def mmcsplat_segmenters() -> list[Registration]:
    segmenters = "mmcsplat.plugins.segmenters"
    return [
        Registration("onnx-semantic", f"{segmenters}.onnx_semantic:OnnxSemanticSegmenter",
                     "any ONNX semantic-segmentation model (a local file, or a URL fetched once by its SHA-256, and its sidecar) on onnxruntime's CPU",
                     unavailable=needs_modules("onnxruntime")),
        Registration("background", f"{segmenters}.background:BackgroundSegmenter",
                     "OpenCV background subtraction over each camera's sequence (MOG2, KNN or median)"),
        Registration("keypoints", f"{segmenters}.keypoints:KeypointSegmenter",
                     "the filled skeleton of 2D keypoints (OpenPose, SLEAP, DeepLabCut), optionally refined against the clean plate"),
        Registration("parallax", f"{segmenters}.parallax:ParallaxSegmenter",
                     "what the calibrated cameras agree stands off the floor (plane plus parallax, fused over voxels): no keypoints, plates or model"),
        Registration("precomputed", f"{segmenters}.precomputed:PrecomputedSegmenter",
                     "the masks the session already holds (d3dgs, D-NeRF, synthetic ground truth)"),
    ]


@hookimpl
def mmcsplat_landmarks() -> list[Registration]:
    return [
        Registration("trc", "mmcsplat.plugins.landmarks.files:TrcLandmarks",
                     "a TRC file of marker trajectories (OpenSim, Pose2Sim's triangulated joints; Y-up axes by default)"),
        Registration("csv", "mmcsplat.plugins.landmarks.files:CsvLandmarks",
                     "a CSV file of name,x,y,z (one frame) or frame,time,name,x,y,z rows"),
        Registration("synthetic", "mmcsplat.plugins.landmarks.synthetic:SyntheticJoints",
                     "the joints of a synthetic capture (its ground_truth.zarr)"),
        Registration("openpose", "mmcsplat.plugins.landmarks.openpose:OpenPoseKeypoints",
                     "OpenPose JSON keypoints per camera (as Pose2Sim writes them), triangulated in the session's cameras"),
        Registration("deeplabcut", "mmcsplat.plugins.landmarks.deeplabcut:DeepLabCutKeypoints",
                     "DeepLabCut CSV or HDF5 keypoints per camera (anipose's pose-2d), triangulated in the session's cameras"),
        Registration("sleap", "mmcsplat.plugins.landmarks.sleap:SleapKeypoints",
                     "SLEAP keypoints per camera (.analysis.h5 or .slp), triangulated in the session's cameras"),
        Registration("freemocap", "mmcsplat.plugins.landmarks.freemocap:FreeMoCapKeypoints",
                     "FreeMoCap's 2D keypoints of every camera (MediaPipe or YOLO, one .npy file), triangulated in the session's cameras"),
        Registration("caliscope", "mmcsplat.plugins.landmarks.caliscope:CaliscopeKeypoints",
                     "Caliscope's 2D keypoints of every camera (a body tracker's xy_TRACKER.csv), triangulated in the session's cameras"),
        Registration("opencap", "mmcsplat.plugins.landmarks.opencap:OpencapKeypoints",
                     "an OpenCap session's 2D keypoints of every phone (OutputPkl/TRIAL_keypoints.pkl), placed in its synchronised videos by "
                     "the trial's markers, triangulated in the session's cameras"),
    ]
