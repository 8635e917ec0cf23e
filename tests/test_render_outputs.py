"""mmcsplat render: camera paths, browser-playable videos, the tracking figure, depth; on a tiny tracked run."""

from __future__ import annotations

import shutil

import attrs
import cv2
import numpy as np
import pytest
from fitting_scene import ring_camera
from render_fixtures import add_tracks, fitted_run

from mmcsplat.cli import main
from mmcsplat.outputs.camera_path import camera_path, interpolate_camera, ring_order
from mmcsplat.outputs.renders import default_frames_per_segment, draw_trails, trajectory_colors, trajectory_gaussians
from mmcsplat.outputs.video import VideoInfo, parse_video_stream, probe_video, write_video
from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import InputError

FRAMES = 4
TRAIN = 4  # the fitting scene's five cameras less the held-out cam_0
# 48×36 scaled by 0.75 is 36×27: odd, so the videos are padded to 36×28.
SCALE, WIDTH, HEIGHT = 0.75, 36, 27


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(a tracked run, the same fit without tracks)."""
    root = tmp_path_factory.mktemp("render")
    run = fitted_run(root, iterations=1)
    static = root / "static"
    shutil.copytree(run, static)
    return add_tracks(run, FRAMES), static


@pytest.fixture(scope="module")
def rendered(runs, tmp_path_factory):
    out = tmp_path_factory.mktemp("renders")
    status = main(["render", str(runs[0]), "--novel", "--trajectories", "--depth", "--frames-per-segment", "1",
                   "--backend", "torch-reference", "--scale", str(SCALE), "--out", str(out), "--no-progress"])
    assert status == 0
    return out


def decoded(path):
    """(frame rate, frames) of a video, decoded by OpenCV: another decoder than the one that wrote it."""
    capture = cv2.VideoCapture(str(path))
    try:
        frames = []
        while (frame := capture.read()[1]) is not None:
            frames.append(frame)
        return capture.get(cv2.CAP_PROP_FPS), frames
    finally:
        capture.release()


def test_path_passes_through_the_training_cameras_in_ring_order():
    rig = [ring_camera(f"cam_{i}", 2 * np.pi * i / 6) for i in range(6)]
    shuffled = [rig[i] for i in (0, 3, 1, 5, 2, 4)]
    assert [camera.name for camera in ring_order(shuffled)] == [camera.name for camera in rig]
    path = camera_path(shuffled, 4)
    assert len(path) == 24
    for i, camera in enumerate(rig):
        np.testing.assert_allclose(path[4 * i].R, camera.R, atol=1e-9)
        np.testing.assert_allclose(path[4 * i].t, camera.t, atol=1e-9)
        np.testing.assert_allclose(path[4 * i].K, camera.K, atol=1e-9)


def test_interpolation_slerps_rotation_and_lerps_centre_and_intrinsics():
    a, b = ring_camera("a", 0.0), ring_camera("b", 1.0, radius=1.5)
    K = b.K.copy()
    K[0, 0] = K[1, 1] = 60.0
    b = attrs.evolve(b, K=K)
    middle = interpolate_camera(a, b, 0.5, "m")
    np.testing.assert_allclose(middle.center, (a.center + b.center) / 2, atol=1e-12)
    np.testing.assert_allclose(middle.K, (a.K + b.K) / 2, atol=1e-12)
    half = np.arccos((np.trace(a.R.T @ b.R) - 1) / 2) / 2
    for end in (a, b):
        np.testing.assert_allclose(np.arccos(np.clip((np.trace(end.R.T @ middle.R) - 1) / 2, -1, 1)), half, atol=1e-9)
    np.testing.assert_allclose(interpolate_camera(a, b, 1.0, "e").world_to_camera, b.world_to_camera, atol=1e-9)


def test_path_scales_cameras_to_one_size():
    small = ring_camera("small", 1.0).scaled(0.5)
    path = camera_path([ring_camera("big", 0.0), small], 2)
    assert {(camera.width, camera.height) for camera in path} == {(48, 36)}
    np.testing.assert_allclose(path[2].K, ring_camera("small", 1.0).K, atol=1e-9)


def test_videos_decode_as_browser_playable_h264(rendered):
    expected = {"novel.mp4": TRAIN * 1, "trajectories_cam_0.mp4": FRAMES, "depth_cam_0.mp4": FRAMES}
    for name, count in expected.items():
        info = probe_video(rendered / name, count_frames=True)
        assert (info.codec, info.pix_fmt, info.width, info.height, info.frames) == ("h264", "yuv420p", WIDTH, HEIGHT + 1, count), name
        fps, frames = decoded(rendered / name)
        assert len(frames) == count and fps == 30.0
        assert max(frame.max() for frame in frames) > 50, f"{name} is black"
    assert not [path.name for path in rendered.iterdir() if path.name.startswith(".")], "temporary files left behind"


def test_trajectory_strip_holds_evenly_spaced_frames(rendered):
    strip = cv2.imread(str(rendered / "trajectories_cam_0.png"))
    assert strip.shape == (HEIGHT, WIDTH * FRAMES, 3)  # four frames: 0, 1, 2, 3 (five spaced over four frames)


def test_novel_view_of_a_run_without_tracks(runs, tmp_path):
    status = main(["render", str(runs[1]), "--novel", "--backend", "torch-reference", "--frames-per-segment", "1",
                   "--scale", "0.5", "--out", str(tmp_path), "--no-progress"])
    assert status == 0
    assert probe_video(tmp_path / "novel.mp4", count_frames=True).frames == TRAIN
    assert default_frames_per_segment(1, TRAIN) == 15 and default_frames_per_segment(400, 7) == 58


def test_trajectory_choice_and_colours_are_stable_per_gaussian(runs):
    states = RunStates(runs[0])
    chosen = trajectory_gaussians(states)
    np.testing.assert_array_equal(chosen, trajectory_gaussians(RunStates(runs[0])))
    foreground = states.foreground()
    assert len(foreground) and np.isin(chosen, foreground).all()
    assert len(chosen) == max(1, round(0.02 * len(foreground)))
    everyone = np.arange(500)
    colours = trajectory_colors(everyone)
    np.testing.assert_array_equal(trajectory_colors(everyone[[7, 300, 42]]), colours[[7, 300, 42]])
    assert len({tuple(c) for c in colours[:50]}) == 50


def test_trails_end_at_the_newest_position_in_their_colour():
    image = np.zeros((40, 60, 3), np.uint8)
    trails = np.array([[[10.0, 10.0], [50.0, 30.0]], [[20.0, 10.0], [50.0, 20.0]], [[30.0, 10.0], [50.0, 10.0]]])
    valid = np.array([[True, True], [True, False], [True, True]])
    colors = np.array([[255, 0, 0], [0, 255, 0]], np.uint8)
    drawn = draw_trails(image, trails, valid, colors)
    for row, column, channel in ((10, 30, 0), (10, 20, 0), (10, 50, 1)):  # anti-aliased: mostly the trail's colour
        pixel = drawn[row, column]
        assert pixel[channel] > 150 and pixel.sum() == pixel[channel], (row, column, pixel)
    assert not drawn[30, 50].any(), "a trail continued past an invalid position"
    assert not image.any(), "the input image was drawn on"


def test_write_video_pads_odd_sizes_and_is_atomic(tmp_path):
    frames = [np.full((9, 11, 3), 40 * i, np.uint8) for i in range(3)]
    info = write_video(tmp_path / "odd.mp4", frames, fps=10)
    assert (info.width, info.height, info.frames) == (12, 10, 3)

    def failing():
        yield frames[0]
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="crashed"):
        write_video(tmp_path / "broken.mp4", failing(), fps=10)
    with pytest.raises(ValueError, match="frame 1 is 5×4"):
        write_video(tmp_path / "ragged.mp4", [frames[0], np.zeros((4, 5, 3), np.uint8)], fps=10)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["odd.mp4"]


def test_clear_errors(runs, tmp_path, capsys):
    assert main(["render", str(tmp_path), "--novel"]) == 2
    assert "checkpoint.pt" in capsys.readouterr().err
    assert main(["render", str(runs[0]), "--novel", "--depth", "--camera", "cam_9", "--out", str(tmp_path)]) == 2
    assert "unknown camera 'cam_9'" in capsys.readouterr().err
    assert not (tmp_path / "novel.mp4").exists(), "rendered before checking the camera"
    assert main(["render", str(runs[0])]) == 2
    assert "--novel, --trajectories, --depth or --landmarks" in capsys.readouterr().err


def test_probe_reads_the_stream_line_with_commas_inside_parentheses(tmp_path):
    header = ("Input #0, mov,mp4,m4a,3gp,3g2,mj2, from 'x.mp4':\n"
              "  Stream #0:0[0x1](und): Video: h264 (High) (avc1 / 0x31637661), yuv420p(tv, bt709, progressive), "
              "270x481 [SAR 1:1 DAR 9:16], 2500 kb/s, 29.97 fps, 29.97 tbr, 15360 tbn (default)\n")
    assert parse_video_stream(header) == VideoInfo("h264", "yuv420p", 270, 481, 29.97)
    assert parse_video_stream("  Stream #0:0: Audio: aac, 48000 Hz, stereo\n") is None
    not_a_video = tmp_path / "notes.mp4"
    not_a_video.write_text("not a video")
    with pytest.raises(InputError, match="notes.mp4: ffmpeg finds no video stream"):
        probe_video(not_a_video)
