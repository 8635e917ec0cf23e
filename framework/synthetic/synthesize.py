"""The synthetic capture end to end: configuration, ground-truth motion, rendering every camera frame by
frame, and writing through :class:`~.writer.CaptureWriter`."""

from __future__ import annotations

import time
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.ground_truth import GROUND_TRUTH
from mmcsplat.synthetic.body import BodyPose, Part, forward_kinematics, infant_parts, surface_points
from mmcsplat.synthetic.cameras import RING_HEIGHT, RING_RADIUS, ring_cameras
from mmcsplat.synthetic.motion import FREQUENCY_RANGE, MOTIONS, RANGES, Motion
from mmcsplat.synthetic.scene import AMBIENT, DIFFUSE, LIGHT, AdultLeg, ViewRenderer
from mmcsplat.synthetic.textures import MAT_HALF_SIZE
from mmcsplat.synthetic.writer import CALIBRATION, VIDEOS, CaptureWriter


def _at_least(minimum: int):
    def check(instance: SynthConfig, attribute: attrs.Attribute, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
            raise InputError(f"{attribute.name} must be an integer ≥ {minimum}, got {value!r}")

    return check


def _positive(instance: SynthConfig, attribute: attrs.Attribute, value: float) -> None:
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"{attribute.name} must be a positive number, got {value!r}")


def _finite(instance: SynthConfig, attribute: attrs.Attribute, value: float) -> None:
    if not np.isfinite(value):
        raise InputError(f"{attribute.name} must be a finite number, got {value!r}")


def _one_of(choices: tuple[str, ...]):
    def check(instance: SynthConfig, attribute: attrs.Attribute, value: str) -> None:
        if value not in choices:
            raise InputError(f"{attribute.name} must be one of {', '.join(choices)}, got {value!r}")

    return check


@attrs.frozen
class SynthConfig:
    """What to synthesise: ``frames`` frames at ``fps`` from ``cameras`` cameras of ``width`` × ``height``
    pixels; ``seed`` fixes the rig's small variations and the motion; ``adult_leg`` adds an adult's leg
    standing beside the mat (in some views, never in the subject mask); ``samples``² rays per pixel
    anti-alias the colour; ``slide`` moves the whole infant along +x at that many metres per second
    (at about 1 m/s it leaves some cameras' views within a second: a failure regime for studies);
    ``motion`` picks the variant of :mod:`~.motion`: ``natural``, ``still-trunk`` (only the limbs move) or
    ``fast-kicks`` (the feet move about their own width between frames at 30 fps)."""

    frames: int = attrs.field(default=30, validator=_at_least(1))
    cameras: int = attrs.field(default=8, validator=_at_least(1))
    width: int = attrs.field(default=256, validator=_at_least(16))
    height: int = attrs.field(default=192, validator=_at_least(16))
    seed: int = attrs.field(default=0, validator=_at_least(0))
    fps: float = attrs.field(default=30.0, converter=float, validator=_positive)
    adult_leg: bool = True
    samples: int = attrs.field(default=2, validator=_at_least(1))
    slide: float = attrs.field(default=0.0, converter=float, validator=_finite)
    motion: str = attrs.field(default="natural", validator=_one_of(MOTIONS))


@attrs.frozen(eq=False)
class SynthResult:
    """What :func:`synthesize` wrote: the capture folder and its files, and the cameras (as calibrated,
    with distortion)."""

    out_dir: Path
    cameras: tuple[Camera, ...]
    videos: dict[str, Path]
    calibration: Path
    ground_truth: Path
    num_frames: int
    fps: float
    seconds: float


def infant_motion(config: SynthConfig) -> tuple[tuple[Part, ...], np.ndarray, BodyPose]:
    """(body parts, frame times in seconds [T], pose of every part at every frame) of the infant that
    ``config``'s seed, frame count, frame rate and slide describe."""
    parts = infant_parts()
    motion = Motion.random(parts, np.random.default_rng([config.seed, 2]), config.motion)
    times = np.arange(config.frames) / config.fps
    poses = forward_kinematics(parts, motion.rotvecs(times))
    if config.slide:
        poses = BodyPose(poses.rotations, poses.origins + config.slide * times[:, None, None] * np.array([1.0, 0.0, 0.0]))
    return parts, times, poses


def synthesize(out_dir: str | Path, config: SynthConfig = SynthConfig(), *, overwrite: bool = False, progress: bool = True) -> SynthResult:
    """Render the synthetic infant capture into ``out_dir``: ``videos/<camera>.mp4``, an anipose
    ``calibration.toml``, ``plates/<camera>.png`` (clean plates: the empty mat) and ``ground_truth.zarr``
    (masks, depth, surface points, joints).

    Frames stream to disk one at a time; the folder appears only once complete. ``out_dir`` must not
    exist or be empty unless ``overwrite``.
    """
    from tqdm import tqdm

    started = time.perf_counter()
    out_dir = Path(out_dir)
    cameras = ring_cameras(config.cameras, config.width, config.height, np.random.default_rng([config.seed, 1]))
    leg = AdultLeg.beside_mat(np.pi / config.cameras) if config.adult_leg else None  # between cam_0 and cam_1
    parts, times, poses = infant_motion(config)
    point_local, point_part = surface_points(parts)
    with CaptureWriter(out_dir, cameras, config.frames, config.fps, overwrite) as writer:
        writer.write_array("surface_points", poses.to_world(point_part, point_local).astype(np.float32),
                           {"surface_point_parts": [parts[i].name for i in point_part], "units": "m"})  # fmt: skip
        writer.write_array("joints", poses.origins[:, 1:].astype(np.float32), {"joint_names": [p.joint for p in parts[1:]], "units": "m"})
        views = [ViewRenderer(camera, config.samples, leg) for camera in tqdm(cameras, desc="synth: cameras", disable=not progress)]
        for c, view in enumerate(views):
            writer.write_plate(c, view.plate())
        for t in tqdm(range(config.frames), desc="synth: frames", unit="frame", disable=not progress):
            pose = BodyPose(poses.rotations[t], poses.origins[t])
            for c, view in enumerate(views):
                writer.write_frame(t, c, view.render(parts, pose))
        attributes = {
            "generator": "mmcsplat synth",
            "fps": config.fps,
            "seed": config.seed,
            "num_frames": config.frames,
            "frame_times": times.tolist(),
            "cameras": [camera.name for camera in cameras],
            "config": attrs.asdict(config),
            "scene": scene_description(parts, leg),
            "motion": {"kind": config.motion, "ranges_rad": {k: [list(axis) for axis in v] for k, v in RANGES.items()},
                       "frequency_hz": list(FREQUENCY_RANGE)},
        }
        writer.commit(attributes, {"generator": "mmcsplat synth", "seed": config.seed, "fps": config.fps})
    return SynthResult(
        out_dir,
        tuple(cameras),
        {camera.name: out_dir / VIDEOS / f"{camera.name}.mp4" for camera in cameras},
        out_dir / CALIBRATION,
        out_dir / GROUND_TRUTH,
        config.frames,
        config.fps,
        time.perf_counter() - started,
    )


def scene_description(parts: tuple[Part, ...], leg: AdultLeg | None) -> dict:
    """The scene's parameters as JSON-ready data (stored with the ground truth)."""
    return {
        "world": "metres, z up, mat at z = 0; infant supine along x, head towards +x, its right towards +y",
        "parts": [
            {
                "name": part.name,
                "parent": parts[part.parent].name if part.parent >= 0 else None,
                "joint": part.joint,
                "offset": part.offset.tolist(),
                "rest_rotation": part.rest.tolist(),
                "ellipsoid_centre": part.centre.tolist(),
                "ellipsoid_radii": part.radii.tolist(),
                "material": part.material,
            }
            for part in parts
        ],
        "mat_half_size": list(MAT_HALF_SIZE),
        "camera_ring": {"radius": RING_RADIUS, "height": RING_HEIGHT},
        "light_direction": LIGHT.tolist(),
        "ambient": AMBIENT,
        "diffuse": DIFFUSE,
        "adult_leg": leg.describe() if leg is not None else None,
    }
