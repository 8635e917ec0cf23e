"""The ``images`` reader: per-camera image folders plus a calibration, read lazily and ingested."""

from __future__ import annotations

from pathlib import Path

import attrs
import cv2
import numpy as np
import pytest
import rig_fixtures as rig

from mmcsplat.configuration.registry import default_registry
from mmcsplat.datasets.images import ImageSequenceReader
from mmcsplat.pipeline.ingest import detect_format, ingest
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.calibration import write_calibration
from mmcsplat.storage.camera_names import name_key, natural_key


def _capture(folder: Path, names=("c1", "c2", "c3"), frames: int = 3) -> list:
    cameras = rig.ring_cameras(names)
    folder.mkdir(parents=True)
    write_calibration(folder / "calibration.toml", cameras)
    rig.write_image_folders(folder, cameras, frames)
    return cameras


def test_name_rules() -> None:
    assert name_key("cam_01") == name_key("cam01") == name_key("Cam-1") == ("cam", 1)
    assert name_key("cam_01") != name_key("cam_10")
    assert sorted(["frame10.png", "frame2.png", "frame1.png"], key=natural_key) == ["frame1.png", "frame2.png", "frame10.png"]


def test_reads_frames_in_natural_order_lazily(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    _capture(source, names=("c1",), frames=12)
    reader = ImageSequenceReader(fps=25)
    assert reader.detect(source) and detect_format(source) == "images"
    recording = reader.open(source)
    assert (recording.num_frames, recording.fps, recording.has_masks) == (12, 25.0, False)
    frames = recording.frames("c1", range(2, 12, 4))
    first = next(frames)  # a generator: frames are decoded one at a time
    assert first.t == 2 and int(np.median(first.rgb)) == rig.background_level(2)
    assert [f.t for f in frames] == [6, 10]
    # frame10.png is frame 10 (not frame 2, as text order would have it).
    assert int(np.median(next(recording.frames("c1", range(10, 11))).rgb)) == rig.background_level(10)


def test_a_frame_rate_the_capture_does_not_state_is_assumed_aloud(tmp_path: Path, recwarn) -> None:
    """Images carry no frame rate: 30 fps is assumed with a warning (a tracker's steps a frame follow the rate),
    unless the reader is given one or the capture has a single frame."""
    _capture(tmp_path / "moving", names=("c1",), frames=2)
    _capture(tmp_path / "still", names=("c1",), frames=1)
    with pytest.warns(UserWarning, match="moving: the capture states no frame rate; assuming 30 fps .*--reader-set fps=N"):
        assert ImageSequenceReader().open(tmp_path / "moving").fps == 30.0
    assert ImageSequenceReader(fps=60).open(tmp_path / "moving").fps == 60.0
    assert ImageSequenceReader().open(tmp_path / "still").fps == 30.0
    assert not [warning for warning in recwarn if "frame rate" in str(warning.message)]


def test_ingest_undistorts_exactly(tmp_path: Path) -> None:
    calibrated = _capture(tmp_path / "capture")
    session = ingest(tmp_path / "capture", tmp_path / "out.zarr", progress=False)
    for camera in calibrated:
        stored = session.camera(camera.name)
        assert not stored.is_distorted
        # Lossless PNGs: markers land within 0.3 px of the undistorted pinhole projection …
        assert rig.marker_offsets(session.frame(1, camera.name).rgb, stored).max() < 0.3
        # … and of the original distorted projection in the original image: the helper measures truly.
        assert rig.marker_offsets(rig.frame_image(camera, 1), stored).max() > 2.0


def test_images_subfolder_fuzzy_names_and_truncation(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    cameras = rig.ring_cameras(["cam_01", "cam_02"])
    source.mkdir()
    write_calibration(source / "calibration.toml", cameras)
    rig.write_image_folders(source / "images", cameras, 3)
    (source / "images" / "cam_02").rename(source / "images" / "CAM2")
    (source / "images" / "CAM2" / "frame2.png").unlink()
    with pytest.warns(UserWarning, match=r"differ in length \(cam_01: 3, cam_02: 2\)"):
        recording = ImageSequenceReader().open(source)
    assert recording.num_frames == 2
    assert recording.describe()["folders"]["cam_02"].endswith("CAM2")


def test_bad_inputs(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    _capture(source, frames=2)
    (source / "c2" / "frame1.png").write_bytes(b"not a png")
    recording = ImageSequenceReader().open(source)
    with pytest.raises(ValueError, match=r"c2/frame1\.png: not a readable image"):
        list(recording.frames("c2", range(2)))
    out = tmp_path / "out.zarr"
    with pytest.raises(ValueError, match="not a readable image"):
        ingest(source, out, progress=False)
    assert rig.no_session_left(out)

    cv2.imwrite(str(source / "c2" / "frame1.png"), np.zeros((10, 10, 3), np.uint8))  # a different size
    with pytest.raises(ValueError, match=r"camera 'c2' frame 1: decoded shape \(10, 10, 3\), expected \(96, 128, 3\)"):
        ingest(source, out, progress=False)
    assert rig.no_session_left(out)

    for path in (source / "c3").iterdir():
        path.unlink()
    (source / "c3").rmdir()
    with pytest.raises(FileNotFoundError, match=r"no image folder for calibrated camera 'c3' \(found: c1, c2\)"):
        ImageSequenceReader().open(source)
    with pytest.raises(ValueError, match="size_mismatch"):
        ImageSequenceReader(size_mismatch="stretch")


@pytest.mark.parametrize("name", ["images", "d3dgs"])
@pytest.mark.parametrize("fps, message", [
    (0, "fps must be a finite number > 0, got 0.0"),
    (-25, "fps must be a finite number > 0, got -25.0"),
    (float("inf"), "fps must be a finite number > 0, got inf"),
])
def test_readers_refuse_a_frame_rate_that_is_not_positive(name: str, fps, message: str) -> None:
    with pytest.raises(InputError, match=f"reader '{name}': {message}"):
        default_registry().create("reader", name, fps=fps)


@pytest.mark.parametrize(("name", "kind"), [("images", "a number or none"), ("d3dgs", "a number")])
def test_readers_refuse_a_frame_rate_that_is_not_a_number(name: str, kind: str) -> None:
    """``images`` may be given none (its capture states no rate); ``d3dgs`` has a rate of its own."""
    with pytest.raises(InputError, match=f"reader '{name}': parameter 'fps' must be {kind}, got '25'"):
        default_registry().create("reader", name, fps="25")


def test_reader_parameters_keep_their_defaults() -> None:
    registry = default_registry()
    assert registry.create("reader", "images") == ImageSequenceReader(fps=None, size_mismatch="scale")
    assert ImageSequenceReader(fps=25).fps == 25.0 and isinstance(ImageSequenceReader(fps=25).fps, float)
    assert registry.create("reader", "images", fps=25, size_mismatch="crop").size_mismatch == "crop"
    with pytest.raises(InputError, match="reader 'videos': size_mismatch must be one of 'scale', 'crop', 'error', got 'stretch'"):
        registry.create("reader", "videos", size_mismatch="stretch")


def test_a_duplicated_camera_left_out_with_cameras_is_never_checked(tmp_path: Path, capsys) -> None:
    from mmcsplat.cli import main
    from mmcsplat.storage.session import SessionReader

    source = tmp_path / "capture"
    cameras = _capture(source)
    # The anipose mouse case: a camera's table copied under another name (same pose), with its own video/images.
    copy = attrs.evolve(cameras[2], name="c4")
    write_calibration(source / "calibration.toml", [*cameras, copy])
    rig.write_image_folders(source, [copy], 3)
    assert main(["ingest", str(source), str(tmp_path / "all.zarr"), "--no-progress"]) == 2
    assert "cameras 'c3' and 'c4' have the same pose (a copied table?): leave the copy out with --cameras" in capsys.readouterr().err
    command = ["ingest", str(source), str(tmp_path / "s.zarr"), "--cameras", "c1,c2,c3", "--holdout", "c3", "--no-progress"]
    assert main(command) == 0
    session = SessionReader(tmp_path / "s.zarr")
    assert session.camera_names == ("c1", "c2", "c3") and session.heldout == ("c3",)
    with pytest.raises(InputError, match=r"no camera named 'c9'"):
        ImageSequenceReader(cameras=["c1", "c9"]).open(source)


def test_a_real_calibration_with_a_copied_table_reads_without_it(tmp_path: Path) -> None:
    real = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "aniposelib_calibrations" / "allen_mouse_7cam.toml"
    if not real.is_file():
        pytest.skip(f"shared real data not found at {real}")
    from mmcsplat.storage.calibration import read_calibration

    names = [camera.name for camera in read_calibration(real, "mm")]
    text = real.read_text()
    first = text[text.index("[cam_0]") : text.index("[cam_1]")]
    broken = tmp_path / "calibration.toml"
    broken.write_text(text + "\n" + first.replace("[cam_0]", "[cam_7]").replace(f'name = "{names[0]}"', 'name = "copy"'))
    with pytest.raises(InputError, match=f"cameras '{names[0]}' and 'copy' have the same pose"):
        read_calibration(broken, "mm")
    assert [camera.name for camera in read_calibration(broken, "mm", names)] == names


def test_masks_folder_by_image_name_and_rgba_alpha(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    cameras = _capture(source, names=("c1", "c2"), frames=2)
    for camera in cameras:
        (source / "masks" / camera.name).mkdir(parents=True)
        for t in range(2):
            mask = np.zeros((camera.height, camera.width), np.uint8)
            mask[10 * (t + 1) :, :] = 255
            cv2.imwrite(str(source / "masks" / camera.name / f"frame{t}.png"), mask)
    recording = ImageSequenceReader().open(source)
    assert recording.has_masks
    frames = list(recording.frames("c2", range(2)))
    assert [int(frame.mask.sum()) for frame in frames] == [(96 - 10) * 128, (96 - 20) * 128]
    (source / "masks" / "c2" / "frame1.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"masks: no mask for 1 frame\(s\): c2/frame1"):
        ImageSequenceReader().open(source)

    # Without a masks folder, RGBA images carry their masks in alpha.
    rgba = tmp_path / "rgba"
    cameras = _capture(rgba, names=("c1", "c2"), frames=2)
    for camera in cameras:
        for t in range(2):
            path = rgba / camera.name / f"frame{t}.png"
            image = cv2.imread(str(path))
            alpha = np.zeros(image.shape[:2], np.uint8)
            alpha[:, 64:] = 255
            cv2.imwrite(str(path), np.dstack([image, alpha]))
    session = ingest(rgba, tmp_path / "rgba.zarr", progress=False)
    assert session.has_source_mask("c1") and 0.3 < session.frame(1, "c1").mask.mean() < 0.7


@pytest.mark.parametrize("named", ["openpose", "pose2sim"])
def test_keypoints_of_an_image_folder_numbered_from_one_land_on_their_images(tmp_path: Path, named: str) -> None:
    """ffmpeg numbers the frames it extracts from 1. OpenPose run on the folder names each JSON after its image
    (``frame_0001_keypoints.json``); Pose2Sim after its image and its position from 0 (``frame_0001_000000.json``).
    Either way frame t's detections are its own image's (OpenPose's were read one image late)."""
    import json
    import warnings

    from mmcsplat.plugins.landmarks.openpose import MODELS, OpenPoseKeypoints

    capture = tmp_path / "capture"
    cameras = rig.ring_cameras(["cam_0", "cam_1"])
    (capture / "calibration").mkdir(parents=True)
    write_calibration(capture / "calibration" / "calibration.toml", cameras)
    body = np.random.default_rng(0).uniform(-0.25, 0.25, (len(MODELS["BODY_25B"]), 3))
    for camera in cameras:
        (capture / "images" / camera.name).mkdir(parents=True)
        (capture / "pose" / camera.name).mkdir(parents=True)
        for position, number in enumerate((1, 2, 3)):
            image = cv2.cvtColor(rig.frame_image(camera, number), cv2.COLOR_RGB2BGR)
            assert cv2.imwrite(str(capture / "images" / camera.name / f"frame_{number:04d}.png"), image)
            person = np.column_stack([camera.project(body + [0.08 * number, 0, 0]), np.full(len(body), 0.9)])
            name = f"frame_{number:04d}_keypoints.json" if named == "openpose" else f"frame_{number:04d}_{position:06d}.json"
            (capture / "pose" / camera.name / name).write_text(json.dumps({"people": [{"pose_keypoints_2d": person.ravel().tolist()}]}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no frame rate stated
        session = ingest(capture, tmp_path / "s.zarr", progress=False)
    assert session.provenance["reader"]["first_number"] == 1
    seen = {o.camera: o for o in OpenPoseKeypoints(folder=str(capture / "pose")).observations(session, [0, 1, 2])}
    for camera in cameras:
        for t in range(3):
            np.testing.assert_allclose(seen[camera.name].pixels[t], session.camera(camera.name).project(body + [0.08 * (t + 1), 0, 0]),
                                       atol=0.5)
    if named == "openpose":  # the images moved away: which file is which image can no longer be told, and that is said
        (capture / "images").rename(tmp_path / "elsewhere")
        with pytest.warns(UserWarning, match=r"OpenPose names an image's keypoints after the image, but camera 'cam_0'"):
            OpenPoseKeypoints(folder=str(capture / "pose")).observations(session, [0, 1, 2])
