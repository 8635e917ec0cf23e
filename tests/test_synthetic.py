"""The synthetic infant capture: files, calibration, ground truth consistent with the cameras' projection,
determinism, motion, atomic writes and argument errors. Tiny captures (a few cameras × frames at 64×48)."""

from __future__ import annotations

from pathlib import Path

import attrs
import cv2
import numpy as np
import pytest
import zarr

from mmcsplat.cli import main
from mmcsplat.storage.calibration import read_calibration
from mmcsplat.synthetic import SynthConfig, SynthGroundTruth, synthesize
from mmcsplat.synthetic.body import BodyPose, forward_kinematics, infant_parts, surface_points
from mmcsplat.synthetic.motion import TRUNK, Motion
from mmcsplat.synthetic.scene import AdultLeg, ViewRenderer, cast_body, paint_body
from mmcsplat.synthetic.synthesize import infant_motion

TINY = SynthConfig(frames=4, cameras=3, width=64, height=48, seed=3)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("synth") / "capture", TINY, progress=False)


def decode(path: Path) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, image = capture.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
    capture.release()
    return frames


def test_videos_decode_to_the_rendered_frames(capture):
    assert sorted(p.name for p in (capture.out_dir / "videos").iterdir()) == ["cam_0.mp4", "cam_1.mp4", "cam_2.mp4"]
    truth = SynthGroundTruth(capture.out_dir)
    parts = infant_parts()
    for camera in truth.cameras():
        frames = decode(capture.videos[camera.name])
        assert len(frames) == TINY.frames and frames[0].shape == (TINY.height, TINY.width, 3)
        # Lossless: frame 2 re-rendered from the files' cameras and the seed matches the video exactly.
        view = ViewRenderer(camera, TINY.samples, _leg(capture))
        rgb = view.render(parts, _pose(parts, TINY, 2)).rgb
        np.testing.assert_array_equal(frames[2], rgb)
        assert np.array_equal(view.render(parts, _pose(parts, TINY, 2)).mask > 0, truth.mask(camera.name, 2))


def test_clean_plates_show_the_empty_mat(tmp_path):
    config = attrs.evolve(TINY, frames=1, adult_leg=False)
    result = synthesize(tmp_path / "capture", config, progress=False)
    truth = SynthGroundTruth(result.out_dir)
    for camera in truth.cameras():
        plate = cv2.cvtColor(cv2.imread(str(result.out_dir / "plates" / f"{camera.name}.png")), cv2.COLOR_BGR2RGB)
        frame = decode(result.videos[camera.name])[0]
        # Away from the infant (whose outline pixels mix it in) the frame is the plate, exactly; on it, not.
        near = cv2.dilate(truth.mask(camera.name, 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        np.testing.assert_array_equal(plate[~near], frame[~near])
        assert np.abs(plate[truth.mask(camera.name, 0)].astype(int) - frame[truth.mask(camera.name, 0)]).mean() > 20


def _pose(parts, config: SynthConfig, t: int) -> BodyPose:
    motion = Motion.random(parts, np.random.default_rng([config.seed, 2]))
    pose = forward_kinematics(parts, motion.rotvecs(np.array([t / config.fps])))
    return BodyPose(pose.rotations[0], pose.origins[0])


def _leg(capture) -> AdultLeg:
    return AdultLeg.beside_mat(np.pi / len(capture.cameras))


def test_calibration_reads_back_distorted(capture):
    cameras = read_calibration(capture.calibration)
    assert [c.name for c in cameras] == ["cam_0", "cam_1", "cam_2"]
    for read, written in zip(cameras, capture.cameras):
        assert (read.width, read.height) == (64, 48)
        assert read.distortion[0] < -0.05 and read.distortion[1] > 0  # barrel k1, small k2
        assert read.K[0, 0] == pytest.approx(1740 * 64 / 2048, rel=0.02)
        np.testing.assert_allclose(read.K, written.K, atol=1e-9)
        np.testing.assert_allclose(read.R, written.R, atol=1e-9)
        np.testing.assert_allclose(read.t, written.t, atol=1e-9)
        # On the ring, looking down at the mat centre.
        assert 1.1 < np.hypot(*read.center[:2]) < 1.3 and 0.9 < read.center[2] < 1.1
        assert read.project(np.zeros((1, 3)))[0] == pytest.approx([32, 24], abs=6)


def test_ground_truth_layout(capture):
    group = zarr.open_group(str(capture.ground_truth), mode="r")
    assert group.metadata.zarr_format == 3
    for camera in capture.cameras:
        masks, depth = group["masks"][camera.name], group["depth"][camera.name]
        assert masks.shape == depth.shape == (4, 48, 64) and masks.chunks == depth.chunks == (1, 48, 64)
        assert masks.dtype == np.uint8 and depth.dtype == np.float16
        assert set(np.unique(masks[...])) == {0, 1}
    points, joints = group["surface_points"], group["joints"]
    assert points.dtype == joints.dtype == np.float32
    assert points.shape[0] == joints.shape[0] == 4 and points.shape[1] >= 200 and points.shape[2] == 3
    assert len(points.attrs["surface_point_parts"]) == points.shape[1]
    assert {"head", "torso", "hand_left", "foot_right"} <= set(points.attrs["surface_point_parts"])
    assert len(joints.attrs["joint_names"]) == joints.shape[1] and "knee_left" in joints.attrs["joint_names"]
    assert group.attrs["fps"] == 30.0 and group.attrs["seed"] == 3 and group.attrs["config"]["cameras"] == 3
    assert group.attrs["scene"]["adult_leg"] is not None


def test_masks_and_depth_match_projected_surface_points(capture):
    truth = SynthGroundTruth(capture.out_dir)
    for camera in truth.cameras():
        for t in range(TINY.frames):
            mask, depth = truth.mask(camera.name, t), truth.depth(camera.name, t)
            assert mask.sum() > 40
            assert np.all(depth[mask] > 0.8) and np.all(depth[mask] < 2.0)
            assert (depth == 0).any() and (depth > 0).mean() > 0.5  # beyond the floor: no surface
            front = _front_points(truth, camera, t)
            assert front.sum() > 100
            pixels = np.round(camera.project(truth.surface_points(t)[front])).astype(int)
            assert mask[pixels[:, 1], pixels[:, 0]].all()


def _front_points(truth: SynthGroundTruth, camera, t: int) -> np.ndarray:
    """[P] bool: surface points ``camera`` sees at their pixel: the depth map there is theirs (within 2 cm).
    Only points off the mat, where a neighbouring pixel could see the mat at the same depth."""
    points = truth.surface_points(t)
    z = (points @ camera.R.T + camera.t)[:, 2]
    pixels = np.round(camera.project(points)).astype(int)
    seen = truth.visible_points(camera, t) & (points[:, 2] > 0.03)
    at = truth.depth(camera.name, t)[np.clip(pixels[:, 1], 0, camera.height - 1), np.clip(pixels[:, 0], 0, camera.width - 1)]
    return seen & (np.abs(at - z) < 0.02)


def test_surface_points_lie_on_the_rendered_surface_through_the_distortion(capture):
    """Rays through the distorted projections (Camera.project) of the surface points hit the body exactly
    at those points when nothing hides them, and never behind them."""
    parts = infant_parts()
    truth = SynthGroundTruth(capture.out_dir)
    pose = _pose(parts, TINY, 1)
    points = truth.surface_points(1).astype(np.float64)
    local, owner = surface_points(parts)
    np.testing.assert_allclose(points, pose.to_world(owner, local), atol=1e-6)
    for camera in capture.cameras:
        pixels = camera.project(points).reshape(-1, 1, 2)
        normalised = cv2.undistortPoints(pixels, camera.K, camera.distortion, criteria=(3, 100, 1e-12)).reshape(-1, 2)
        directions = np.concatenate([normalised, np.ones((len(points), 1))], axis=1) @ camera.R
        n = len(points)
        boxes = np.tile([0, n, 0, 1], (len(parts), 1))
        hits = cast_body(camera.center, directions, np.arange(n).reshape(1, n, 1), boxes, parts, pose, np.full(n, np.inf))
        z = (points @ camera.R.T + camera.t)[:, 2]
        assert np.all(hits.depth <= z + 1e-6)
        assert (np.abs(hits.depth - z) < 1e-6).mean() > 0.3
        assert paint_body(hits, parts, pose).shape == (len(hits.rays), 3)


def test_adult_leg_is_in_some_views_but_never_in_the_mask(tmp_path):
    config = SynthConfig(frames=1, cameras=8, width=64, height=48, samples=1)
    with_leg = SynthGroundTruth(synthesize(tmp_path / "leg", config, progress=False).out_dir)
    without = SynthGroundTruth(synthesize(tmp_path / "none", attrs.evolve(config, adult_leg=False), progress=False).out_dir)
    views_with_leg = 0
    for camera in with_leg.cameras():
        mask = with_leg.mask(camera.name, 0)
        assert np.array_equal(mask, without.mask(camera.name, 0))
        leg = with_leg.depth(camera.name, 0) != without.depth(camera.name, 0)
        if leg.sum() > 10:
            views_with_leg += 1
            near_infant = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            assert not (leg & near_infant).any(), camera.name  # separate components
    assert views_with_leg >= 2


def test_same_seed_same_capture_other_seed_other_motion(tmp_path, capture):
    small = SynthConfig(frames=2, cameras=2, width=32, height=24, seed=3, adult_leg=False)
    first = synthesize(tmp_path / "a", small, progress=False)
    again = synthesize(tmp_path / "b", small, progress=False)
    a, b = SynthGroundTruth(first.out_dir), SynthGroundTruth(again.out_dir)
    np.testing.assert_array_equal(a.surface_points(), b.surface_points())
    for camera in first.cameras:
        np.testing.assert_array_equal(a.depth(camera.name, 1), b.depth(camera.name, 1))
        assert all(np.array_equal(x, y) for x, y in zip(decode(first.videos[camera.name]), decode(again.videos[camera.name])))
    # The motion and rig depend on the seed only, not on the image size or camera count.
    np.testing.assert_array_equal(a.surface_points(), SynthGroundTruth(capture.out_dir).surface_points(slice(0, 2)))
    other = SynthGroundTruth(synthesize(tmp_path / "c", SynthConfig(frames=2, cameras=2, width=32, height=24, seed=4), progress=False).out_dir)
    assert np.abs(other.surface_points(1) - a.surface_points(1)).max() > 0.01
    assert not np.allclose(other.cameras()[0].K, a.cameras()[0].K)


def test_motion_is_smooth_realistic_and_attached():
    parts = infant_parts()
    local, owner = surface_points(parts)
    names = [p.name for p in parts]
    fps = 30.0
    for seed in range(3):
        motion = Motion.random(parts, np.random.default_rng([seed, 2]))
        pose = forward_kinematics(parts, motion.rotvecs(np.arange(150) / fps))  # 5 s
        points = pose.to_world(owner, local)
        steps = np.linalg.norm(np.diff(points, axis=0), axis=-1)
        assert steps.max() < 0.03  # < 0.9 m/s anywhere: smooth at 30 fps
        assert np.abs(np.diff(points, 2, axis=0)).max() < 0.01  # accelerations below 9 m/s²: no jumps
        for end in ("hand_left", "hand_right", "foot_left", "foot_right"):
            centre = points[:, owner == names.index(end)].mean(axis=1)
            travel = np.linalg.norm(centre - centre.mean(axis=0), axis=1).max()
            assert 0.02 < travel < 0.15, (seed, end, travel)
        head = pose.rotations[:, names.index("head")]
        assert np.degrees(np.arccos(np.clip(head[:, :, 2] @ head[0, :, 2], -1, 1))).max() > 10  # the head turns
        assert points[..., 2].min() > -0.005  # the body stays on, not in, the mat
        # Parts stay attached: each joint stays at a fixed place in its parent's frame.
        for i, part in enumerate(parts[1:], start=1):
            offset = np.einsum("tji,tj->ti", pose.rotations[:, part.parent], pose.origins[:, i] - pose.origins[:, part.parent])
            np.testing.assert_allclose(offset, np.broadcast_to(part.offset, offset.shape), atol=1e-9)
    rest = forward_kinematics(parts, np.zeros((len(parts), 3)))
    joints = dict(zip([p.joint for p in parts], rest.origins))
    crown = rest.origins[names.index("head"), 0] + 2 * parts[names.index("head")].radii[0]
    stature = crown - joints["hip_left"][0] + np.linalg.norm(joints["knee_left"] - joints["hip_left"]) + np.linalg.norm(joints["ankle_left"] - joints["knee_left"])
    assert 0.5 < stature < 0.6


def test_ground_truth_frame_selection(capture):
    truth = SynthGroundTruth(capture.out_dir)
    assert truth.surface_points(2).shape == truth.surface_points()[2].shape
    np.testing.assert_array_equal(truth.joints([3, 1]), truth.joints()[[3, 1]])
    with pytest.raises(IndexError, match="frame 4"):
        truth.joints(4)
    with pytest.raises(KeyError, match="cam_9"):
        truth.mask("cam_9", 0)
    with pytest.raises(FileNotFoundError):
        SynthGroundTruth(capture.out_dir / "nowhere")


def test_interrupted_synth_leaves_nothing_and_keeps_an_old_capture(tmp_path, monkeypatch):
    calls = []

    def failing_render(self, parts, pose):
        calls.append(1)
        if len(calls) > 2:
            raise KeyboardInterrupt
        return original(self, parts, pose)

    original = ViewRenderer.render
    monkeypatch.setattr(ViewRenderer, "render", failing_render)
    small = SynthConfig(frames=3, cameras=2, width=32, height=24, adult_leg=False)
    with pytest.raises(KeyboardInterrupt):
        synthesize(tmp_path / "out", small, progress=False)
    assert list(tmp_path.iterdir()) == []
    # A failed --overwrite leaves the previous capture untouched.
    monkeypatch.setattr(ViewRenderer, "render", original)
    synthesize(tmp_path / "out", small, progress=False)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    calls.clear()
    monkeypatch.setattr(ViewRenderer, "render", failing_render)
    with pytest.raises(KeyboardInterrupt):
        synthesize(tmp_path / "out", small, overwrite=True, progress=False)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_existing_output_needs_overwrite(tmp_path):
    small = SynthConfig(frames=1, cameras=1, width=32, height=24, adult_leg=False)
    (tmp_path / "out").mkdir()  # an empty folder is fine
    synthesize(tmp_path / "out", small, progress=False)
    with pytest.raises(FileExistsError, match="--overwrite"):
        synthesize(tmp_path / "out", small, progress=False)
    result = synthesize(tmp_path / "out", SynthConfig(frames=2, cameras=1, width=32, height=24, adult_leg=False), overwrite=True, progress=False)
    assert SynthGroundTruth(result.out_dir).num_frames == 2
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize(
    "field, value, message",
    [("frames", 0, "frames"), ("cameras", 0, "cameras"), ("width", 8, "width"), ("height", 2.5, "height"),
     ("seed", -1, "seed"), ("fps", 0.0, "fps"), ("samples", 0, "samples"), ("slide", float("nan"), "slide"),
     ("motion", "wobbly", "motion must be one of natural, still-trunk, fast-kicks")],
)  # fmt: skip
def test_bad_configuration_is_refused(field, value, message):
    with pytest.raises(ValueError, match=message):
        SynthConfig(**{field: value})


def test_slide_moves_the_whole_infant_along_x(tmp_path):
    still = SynthConfig(frames=2, cameras=1, width=32, height=24, fps=2.0, samples=1, adult_leg=False)
    sliding = attrs.evolve(still, slide=0.5)
    points = [SynthGroundTruth(synthesize(tmp_path / name, config, progress=False).out_dir).surface_points(1)
              for name, config in (("still", still), ("sliding", sliding))]
    # Half a second later at 0.5 m/s: every surface point 0.25 m further along +x, nothing else moved.
    np.testing.assert_allclose(points[1] - points[0], np.broadcast_to([0.25, 0.0, 0.0], points[0].shape), atol=1e-6)


def _part_points(config: SynthConfig) -> dict[str, np.ndarray]:
    """Each part's surface points [T, N, 3] over ``config``'s frames."""
    parts, _, poses = infant_motion(config)
    local, owner = surface_points(parts)
    points = poses.to_world(owner, local)
    return {part.name: points[:, owner == i] for i, part in enumerate(parts)}


def _part_centres(config: SynthConfig) -> dict[str, np.ndarray]:
    """Each part's surface-point centre [T, 3] over ``config``'s frames."""
    return {name: points.mean(axis=1) for name, points in _part_points(config).items()}


def test_still_trunk_moves_only_the_limbs():
    for seed in range(3):
        still = _part_points(SynthConfig(frames=90, seed=seed, motion="still-trunk"))
        natural = _part_points(SynthConfig(frames=90, seed=seed))
        for name, points in still.items():
            travel = np.linalg.norm(points - points[0], axis=-1).max()
            if name.startswith(TRUNK):
                assert travel < 1e-9, (seed, name)  # the same pose in every frame
                assert np.linalg.norm(natural[name] - natural[name][0], axis=-1).max() > 0.002  # where the natural motion moves it
            elif name.startswith(("hand", "foot")):
                centre = points.mean(axis=1)
                assert np.linalg.norm(centre - centre[0], axis=1).max() > 0.02, (seed, name)


def test_fast_kicks_move_a_foot_about_its_width_per_frame():
    foot_width = 2 * infant_parts()[[p.name for p in infant_parts()].index("foot_left")].radii[1]
    for seed in range(3):
        config = SynthConfig(frames=60, seed=seed, motion="fast-kicks")
        centres = _part_centres(config)
        for side in ("left", "right"):
            step = np.linalg.norm(np.diff(centres[f"foot_{side}"], axis=0), axis=1).max()
            assert 0.8 * foot_width < step < 1.5 * foot_width, (seed, side, step / foot_width)
            slow = np.linalg.norm(np.diff(_part_centres(SynthConfig(frames=60, seed=seed))[f"foot_{side}"], axis=0), axis=1).max()
            assert step > 3 * slow  # much faster than the natural motion's feet
        _, _, poses = infant_motion(config)
        local, owner = surface_points(infant_parts())
        assert poses.to_world(owner, local)[..., 2].min() > -0.005  # the kicks stay above the mat


def test_cli(tmp_path, capsys):
    out = tmp_path / "cap"
    assert main(["synth", str(out), "--num-frames", "2", "--num-cameras", "2", "--width", "32", "--height", "24", "--no-adult-leg", "--no-progress", "--seed", "7",
                 "--slide", "0.5", "--motion", "still-trunk"]) == 0
    assert "2 cameras × 2 frames" in capsys.readouterr().out
    truth = SynthGroundTruth(out)
    assert truth.seed == 7 and truth.group.attrs["config"]["adult_leg"] is False and truth.group.attrs["config"]["slide"] == 0.5
    assert truth.group.attrs["config"]["motion"] == "still-trunk" and truth.group.attrs["motion"]["kind"] == "still-trunk"
    assert main(["synth", str(out), "--no-progress"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "bad"), "--num-frames", "0", "--no-progress"]) == 2
    assert "frames must be an integer" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    assert main(["synth", str(tmp_path / "bad"), "--motion", "wobbly", "--no-progress"]) == 2
    assert "motion must be one of" in capsys.readouterr().err


def test_ingested_capture_keeps_masks_aligned_with_the_surface(capture, tmp_path):
    """Through the videos reader and undistortion at ingest, the masks stay on the infant."""
    from mmcsplat.pipeline.ingest import ingest

    session = ingest(capture.out_dir, tmp_path / "session.zarr", progress=False)
    assert session.has("mask") and session.has("depth")
    truth = SynthGroundTruth(capture.out_dir)
    points = truth.surface_points(1)
    for distorted in truth.cameras():
        camera = session.camera(distorted.name)
        assert not camera.is_distorted
        front = _front_points(truth, distorted, 1)
        pixels = np.round(camera.project(points[front])).astype(int)
        inside = np.all((pixels >= 0) & (pixels < [camera.width, camera.height]), axis=1)
        mask = session.frame(1, camera.name).mask
        assert inside.all() and mask[pixels[:, 1], pixels[:, 0]].mean() > 0.9
