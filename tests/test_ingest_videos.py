"""Ingest of the ``videos`` format: small videos made here, bad inputs, atomicity, and the real Pose2Sim demo."""

from __future__ import annotations

import json
import shutil
import subprocess
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import rig_fixtures as rig
import tomli_w

from mmcsplat.cli import main
from mmcsplat.datasets.videos import VideoReader
from mmcsplat.pipeline.image_scale import AUTO_SCALE, resolve_scale
from mmcsplat.pipeline.ingest import Undistorter, detect_format, ingest, parse_frames
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.calibration import read_calibration, write_calibration
from mmcsplat.storage.session import SessionReader

POSE2SIM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"


def _ingest(source: Path, out: Path, **options) -> SessionReader:
    return ingest(source, out, progress=False, **options)


def test_parse_frames() -> None:
    assert parse_frames("0:5") == slice(0, 5, None)
    assert parse_frames("2:10:3") == slice(2, 10, 3)
    assert parse_frames("10:") == slice(10, None, None)
    for bad in ("5", "a:b", "0:5:0", "-1:4", "1:2:3:4"):
        with pytest.raises(ValueError, match="frames"):
            parse_frames(bad)


def test_ingest_undistorts_and_keeps_frame_order(tmp_path: Path) -> None:
    calibrated = rig.make_capture(tmp_path / "capture", frames=4)
    assert detect_format(tmp_path / "capture") == "videos"
    session = _ingest(tmp_path / "capture", tmp_path / "out.zarr")
    assert session.camera_names == ("cam_a", "cam_b")
    assert (session.num_frames, session.fps) == (4, 30.0)
    assert session.provenance["format"] == "videos"
    for camera in calibrated:
        stored = session.camera(camera.name)
        assert not stored.is_distorted and (stored.width, stored.height) == (camera.width, camera.height)
        new_K, _ = cv2.getOptimalNewCameraMatrix(camera.K, camera.distortion, (camera.width, camera.height), 0)
        np.testing.assert_allclose(stored.K, new_K)
        np.testing.assert_allclose(stored.R, camera.R, atol=1e-12)
        for t in range(4):
            rgb = session.frame(t, camera.name).rgb
            assert abs(float(np.median(rgb)) - rig.background_level(t)) < 10, (camera.name, t)
            # Markers sit where the undistorted pinhole camera projects them (mp4v is lossy: 0.5 px).
            assert rig.marker_offsets(rgb, stored).max() < 0.5
        # Without undistortion they would be pixels away: the check above can fail.
        assert rig.marker_offsets(rig.frame_image(camera, 0), stored).max() > 2.0


def test_frames_scale_subset_and_holdout(tmp_path: Path) -> None:
    rig.make_capture(tmp_path / "capture", names=("c1", "c2", "c3"), frames=6)
    session = _ingest(tmp_path / "capture", tmp_path / "out.zarr", frames=slice(1, 6, 2), scale=0.5, cameras=["c3", "c1"], holdout=["c1"])
    assert session.camera_names == ("c3", "c1")
    assert session.heldout == ("c1",) and session.train_cameras == ("c3",)
    assert session.num_frames == 3 and session.fps == 15.0
    np.testing.assert_allclose(session.frame_times, [1 / 30, 3 / 30, 5 / 30])
    full = Undistorter.for_camera(read_calibration(tmp_path / "capture" / "calibration.toml")[2]).camera
    stored = session.camera("c3")
    assert (stored.width, stored.height) == (64, 48)
    np.testing.assert_allclose(stored.K, full.scaled(0.5).K)
    for index, t in enumerate((1, 3, 5)):
        rgb = session.frame(index, "c3").rgb
        assert rgb.shape == (48, 64, 3)
        assert abs(float(np.median(rgb)) - rig.background_level(t)) < 10


def test_frames_past_the_end_are_said_and_a_holdout_outside_the_cameras_is_named(tmp_path: Path) -> None:
    rig.make_capture(tmp_path / "capture", names=("c1", "c2", "c3"), frames=6)
    with pytest.warns(UserWarning, match=r"--frames 4:200: .* has 6 frames; taking frames 4–5 \(2\)"):
        assert _ingest(tmp_path / "capture", tmp_path / "out.zarr", frames=slice(4, 200)).num_frames == 2
    with pytest.raises(InputError, match="--holdout: c2 not among the selected cameras c3, c1"):
        _ingest(tmp_path / "capture", tmp_path / "other.zarr", cameras=["c3", "c1"], holdout=["c2"])


def test_resolve_scale_sizes_the_longer_side_and_never_enlarges() -> None:
    def camera(width: int, height: int) -> object:
        return type("Sized", (), {"width": width, "height": height})()

    assert resolve_scale(AUTO_SCALE, [camera(1088, 1920), camera(1080, 1920)]) == 0.25  # the Pose2Sim demo
    assert resolve_scale(AUTO_SCALE, [camera(1280, 720)]) == 0.375
    assert resolve_scale(AUTO_SCALE, [camera(3840, 2160), camera(1920, 1080)]) == 0.125  # the largest camera decides
    assert resolve_scale(AUTO_SCALE, [camera(256, 192)]) == 1.0
    assert resolve_scale(0.5, []) == 0.5
    for bad in (0, -1.0, "half", 50, float("inf")):  # 50 meant as per cent
        with pytest.raises(InputError, match=r"scale must be a number in \(0, 1\], the share of the recorded size"):
            resolve_scale(bad, [])


def test_an_auto_scale_is_recorded_as_the_number_it_became(tmp_path: Path) -> None:
    rig.make_capture(tmp_path / "capture", frames=2)
    with_auto = _ingest(tmp_path / "capture", tmp_path / "auto.zarr", scale=AUTO_SCALE)
    assert with_auto.provenance["scale"] == 1.0  # 128 × 96 is under 480 px: never enlarged
    assert with_auto.camera("cam_a").width == 128
    assert main(["ingest", str(tmp_path / "capture"), str(tmp_path / "cli.zarr"), "--scale", "auto", "--no-progress"]) == 0
    with pytest.raises(SystemExit):
        main(["ingest", str(tmp_path / "capture"), str(tmp_path / "bad.zarr"), "--scale", "half"])


def _capture(tmp_path: Path, names: list[str], folder: str, frames: list[int], stems: list[str]) -> tuple[Path, list]:
    """A capture folder: a calibration of ring cameras ``names`` and their videos in ``folder``, named ``stems``."""
    source = tmp_path / "capture"
    cameras = rig.ring_cameras(names)
    source.mkdir()
    write_calibration(source / "calibration.toml", cameras)
    rig.write_videos(source / folder, cameras, frames, stems=stems)
    return source, cameras


def test_fuzzy_names_videos_folder_and_truncation(tmp_path: Path) -> None:
    source, _ = _capture(tmp_path, ["cam_01", "cam_02"], "videos", [5, 3], ["cam01", "Cam-2"])
    with pytest.warns(UserWarning, match=r"differ in length \(cam_01: 5, cam_02: 3\); truncating every camera to 3"):
        session = _ingest(source, tmp_path / "out.zarr")
    assert session.num_frames == 3
    assert session.provenance["reader"]["videos"]["cam_02"].endswith("Cam-2.mp4")


def test_cameras_named_by_letter_match_files_as_anipose_names_them(tmp_path: Path) -> None:
    source, cameras = _capture(tmp_path, ["A", "B"], "videos-raw", [3, 3], ["2019-08-02-vid01-camB", "2019-08-02-vid01-camA"])
    session = _ingest(source, tmp_path / "out.zarr")
    assert session.provenance["reader"]["videos"]["A"].endswith("vid01-camA.mp4")
    assert session.provenance["reader"]["videos"]["B"].endswith("vid01-camB.mp4")
    # a second trial beside the first (anipose keeps a session's trials in one folder): which one is asked for
    rig.write_videos(source / "videos-raw", cameras[:1], [3], stems=["2019-08-02-vid02-camA"])
    with pytest.raises(ValueError, match=r"camera 'A' matches several videos \(2019-08-02-vid01-camA.mp4, 2019-08-02-vid02-camA.mp4\); "
                                         r"choose one with camera_map=\{A=\"FILE_STEM\"\}, or every camera's with trial=\"NAME_START\" "
                                         r"\(the reader's camera_map"):
        _ingest(source, tmp_path / "two.zarr")
    rig.write_videos(source / "videos-raw", cameras[1:], [3], stems=["2019-08-02-vid02-camB"])
    session = _ingest(source, tmp_path / "second.zarr", reader_options={"trial": "2019-08-02-vid02"})
    assert session.provenance["reader"]["videos"]["A"].endswith("vid02-camA.mp4")
    assert session.provenance["reader"]["videos"]["B"].endswith("vid02-camB.mp4")
    # a trial whose name starts another's (vid1 and vid10) is still one trial: the name must not go on with its digits
    for trial in ("vid1", "vid10"):
        rig.write_videos(source / "videos-raw", cameras, [3, 3], stems=[f"{trial}-camA", f"{trial}-camB"])
    session = _ingest(source, tmp_path / "vid1.zarr", reader_options={"trial": "vid1"})
    assert session.provenance["reader"]["videos"]["A"].endswith("/vid1-camA.mp4")


def test_size_mismatch_scales_K_with_a_warning(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    cameras = rig.ring_cameras(["a", "b"])
    source.mkdir()
    rig.write_videos(source, cameras, 2)
    # The calibration claims twice the decoded size: a resampled video.
    write_calibration(source / "calibration.toml", [c.scaled(2.0) for c in cameras])
    with pytest.warns(UserWarning, match=r"decodes at 128×96 but camera '[ab]' is calibrated at 256×192; scaling K by \(0\.50000, 0\.50000\)"):
        recording = VideoReader().open(source)
    np.testing.assert_allclose(recording.cameras[0].K, cameras[0].K, atol=1e-9)
    with pytest.raises(ValueError, match=r"calibrated at 256×192 \(size_mismatch='error'\)"):
        VideoReader(size_mismatch="error").open(source)
    with pytest.warns(UserWarning, match=r"keeping K and treating the images as the top-left crop"):
        cropped = VideoReader(size_mismatch="crop").open(source).cameras[0]
    np.testing.assert_allclose(cropped.K, cameras[0].scaled(2.0).K)
    assert (cropped.width, cropped.height) == (128, 96)
    # A crop cannot be larger than the calibrated frame.
    write_calibration(source / "calibration.toml", [c.scaled(0.5) for c in cameras])
    with pytest.raises(ValueError, match="larger than calibrated, so it cannot be a crop"):
        VideoReader(size_mismatch="crop").open(source)


def test_size_mismatch_that_cannot_be_a_rescale_is_an_error(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    cameras = rig.ring_cameras(["a"])
    source.mkdir()
    rig.write_videos(source, cameras, 2)
    rotated = [c.scaled(96 / 128, 128 / 96) for c in cameras]  # portrait calibration of a landscape video
    write_calibration(source / "calibration.toml", rotated)
    with pytest.raises(ValueError, match="aspect ratio differs too much"):
        _ingest(source, tmp_path / "out.zarr")
    assert rig.no_session_left(tmp_path / "out.zarr")


def test_ground_truth_masks_and_depth_are_undistorted_with_the_frames(tmp_path: Path) -> None:
    import zarr

    source = tmp_path / "capture"
    cameras = rig.make_capture(source, frames=3)
    group = zarr.open_group(str(source / "ground_truth.zarr"), mode="w")
    for camera in cameras:
        mask = np.zeros((3, camera.height, camera.width), np.uint8)
        mask[:, 20:70, 30:100] = 1
        group.create_array(f"masks/{camera.name}", data=mask)
        group.create_array(f"depth/{camera.name}", data=(mask * 1.5).astype(np.float16))
    session = _ingest(source, tmp_path / "out.zarr", scale=0.5)
    assert session.has("mask") and session.has("depth")
    frame = session.frame(2, "cam_b")
    assert frame.mask.dtype == bool and frame.mask.shape == (48, 64)
    assert set(np.unique(frame.depth)) == {0.0, 1.5}  # nearest sampling: no blended depth
    np.testing.assert_array_equal(frame.depth > 0, frame.mask)
    assert 0.15 < frame.mask.mean() < 0.5


@pytest.mark.parametrize(
    "breakage, message",
    [
        ("missing_video", r"no video for calibrated camera 'cam_b'"),
        ("garbage_video", r"video .*cam_b\.mp4: cannot"),
        ("malformed_calibration", r"calibration .*calibration\.toml, \[cam_1\]: missing matrix"),
        ("no_calibration", r"no calibration\.toml"),
        ("empty", r"no reader recognises this folder"),
    ],
)
def test_bad_inputs_fail_clearly_and_leave_no_session(tmp_path: Path, breakage: str, message: str) -> None:
    source = tmp_path / "capture"
    rig.make_capture(source)
    if breakage == "missing_video":
        (source / "cam_b.mp4").unlink()
    elif breakage == "garbage_video":
        (source / "cam_b.mp4").write_bytes(np.random.default_rng(0).bytes(4096))
    elif breakage == "malformed_calibration":
        document = {f"cam_{i}": {"name": c.name, "size": [c.width, c.height], "distortions": [0.0] * 5, "rotation": [0.0] * 3,
                                 "translation": [0.0] * 3} | ({"matrix": c.K.tolist()} if i == 0 else {})
                    for i, c in enumerate(rig.ring_cameras(["cam_a", "cam_b"]))}
        (source / "calibration.toml").write_text(tomli_w.dumps(document))
    elif breakage == "no_calibration":
        (source / "calibration.toml").unlink()
    elif breakage == "empty":
        shutil.rmtree(source)
        source.mkdir()
    out = tmp_path / "out.zarr"
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        _ingest(source, out)
    assert rig.no_session_left(out)


def test_cli_reports_bad_input_and_succeeds_on_good(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    source = tmp_path / "capture"
    rig.make_capture(source, names=("x", "y"), frames=2)
    assert main(["ingest", str(source), str(tmp_path / "out.zarr"), "--cameras", "x,z"]) == 2
    assert "no camera named 'z'; cameras are x, y" in capsys.readouterr().err
    assert main(["ingest", str(source), str(tmp_path / "out.zarr"), "--holdout", "x,y"]) == 2
    assert "nothing is left to train on" in capsys.readouterr().err
    assert rig.no_session_left(tmp_path / "out.zarr")
    assert main(["ingest", str(source), str(tmp_path / "out.zarr"), "--format", "videos", "--holdout", "y"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert SessionReader(tmp_path / "out.zarr").heldout == ("y",)
    assert main(["ingest", str(source), str(tmp_path / "out.zarr")]) == 2  # exists: needs --overwrite
    assert "already exists" in capsys.readouterr().err
    assert main(["ingest", str(source), str(tmp_path / "out.zarr"), "--overwrite", "--frames", "1:2"]) == 0
    assert SessionReader(tmp_path / "out.zarr").num_frames == 1


def test_a_relative_source_is_recorded_as_an_absolute_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import zarr

    from mmcsplat.storage.ground_truth import ground_truth_beside

    source = (tmp_path / "capture").resolve()
    rig.make_capture(source, frames=2)
    zarr.open_group(str(source / "ground_truth.zarr"), mode="w")
    monkeypatch.chdir(tmp_path)
    assert main(["ingest", "capture", "out.zarr", "--calibration", "capture/calibration.toml"]) == 0
    monkeypatch.chdir(source)  # read from another working directory
    session = SessionReader(tmp_path / "out.zarr")
    assert session.source == str(source)
    assert session.provenance["reader"]["calibration"] == str(source / "calibration.toml")
    assert ground_truth_beside(session) == source / "ground_truth.zarr"


def test_interrupted_ingest_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rig.make_capture(tmp_path / "capture", frames=3)
    calls = []
    original = Undistorter.rgb

    def interrupt_on_fourth(self, image):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return original(self, image)

    monkeypatch.setattr(Undistorter, "rgb", interrupt_on_fourth)
    with pytest.raises(KeyboardInterrupt):
        _ingest(tmp_path / "capture", tmp_path / "out.zarr")
    assert len(calls) == 4 and rig.no_session_left(tmp_path / "out.zarr")


def test_several_matching_formats_is_an_error(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    cameras = rig.make_capture(source, frames=1)
    rig.write_image_folders(source, cameras, 1)
    with pytest.raises(ValueError, match=r"several formats match \(images, videos\); choose one with --format"):
        _ingest(source, tmp_path / "out.zarr")
    assert _ingest(source, tmp_path / "out.zarr", format="images").num_frames == 1


# ------------------------------------------------------------------------------- the real Pose2Sim demo


def _trc_joints(path: Path) -> np.ndarray:
    """[T, J, 3] joints of a Pose2Sim .trc in the calibration's world frame: (trc Z, trc X, trc Y)."""
    rows = [line.split("\t") for line in path.read_text().splitlines()[5:] if line.strip()]
    values = np.array([[float(v) for v in row[2:] if v.strip()] for row in rows])
    return values.reshape(len(rows), -1, 3)[..., [2, 0, 1]]


def _keypoints(path: Path, min_confidence: float = 0.3) -> np.ndarray:
    """[N, 2] confident OpenPose keypoints of every person in one frame's JSON."""
    people = json.loads(path.read_text())["people"]
    points = np.concatenate([np.reshape(p["pose_keypoints_2d"], (-1, 3)) for p in people])
    return points[points[:, 2] > min_confidence, :2]


def pose2sim_medians(out: Path, frames: slice, scale: float, size_mismatch: str = "scale") -> dict[str, float]:
    """Ingest the Pose2Sim demo and return, per camera, the median distance (in original-resolution px)
    between the projected 3D joints and the nearest confident 2D keypoint, both in the ingested images."""
    calibration = POSE2SIM / "Calib_qualisys.toml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the cam01/cam02 size mismatch is asserted elsewhere
        session = ingest(POSE2SIM, out, calibration=calibration, frames=frames, scale=scale, progress=False,
                         reader_options={"size_mismatch": size_mismatch})
        decoded = {c.name: c for c in VideoReader(size_mismatch=size_mismatch).open(POSE2SIM, calibration).cameras}
    joints = _trc_joints(POSE2SIM / "joints_3d.trc")
    medians = {}
    for name in session.camera_names:
        stored, original = session.camera(name), decoded[name]
        tag = name.replace("_", "")
        distances = []
        for index, t in enumerate(range(*frames.indices(len(joints)))):
            points = _keypoints(POSE2SIM / "pose_2d" / tag / f"{tag}.{t:04d}.json")
            # Into the ingested image space: undistort onto the stored K (which already includes the scale).
            points = cv2.undistortPoints(points.reshape(-1, 1, 2), original.K, original.distortion, P=stored.K).reshape(-1, 2)
            projected = stored.project(joints[t])
            distances.extend(np.linalg.norm(projected[:, None] - points[None], axis=-1).min(axis=1))
            assert session.present(name)[index]
        medians[name] = float(np.median(distances)) / scale
    return medians


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared Pose2Sim demo not found at {POSE2SIM}")
def test_pose2sim_demo_joints_land_on_keypoints(tmp_path: Path) -> None:
    with pytest.warns(UserWarning, match=r"cam0[12]\.mp4 decodes at 1080×1920 but camera 'cam_0[12]' is calibrated at 1088×1920"):
        VideoReader().open(POSE2SIM, POSE2SIM / "Calib_qualisys.toml")
    medians = pose2sim_medians(tmp_path / "pose2sim.zarr", slice(0, 5), scale=0.5)
    assert set(medians) == {"cam_01", "cam_02", "cam_03", "cam_04"}
    assert all(m <= 25.0 for m in medians.values()), medians
    session = SessionReader(tmp_path / "pose2sim.zarr")
    assert (session.camera("cam_01").width, session.camera("cam_03").width) == (540, 544)


def _write_plates(folder: Path, cameras, size_of: dict[str, tuple[int, int]] | None = None) -> None:
    """Each camera's marker image (frame 0) as its clean plate ``folder/<camera>.png``, optionally resized."""
    folder.mkdir(parents=True, exist_ok=True)
    for camera in cameras:
        image = cv2.cvtColor(rig.frame_image(camera, 0), cv2.COLOR_RGB2BGR)
        if size_of and camera.name in size_of:
            image = cv2.resize(image, size_of[camera.name])
        cv2.imwrite(str(folder / f"{camera.name}.png"), image)


def test_clean_plates_are_undistorted_with_the_frames(tmp_path: Path) -> None:
    calibrated = rig.make_capture(tmp_path / "capture", frames=2)
    _write_plates(tmp_path / "capture" / "plates", calibrated)
    session = _ingest(tmp_path / "capture", tmp_path / "out.zarr")
    assert session.provenance["plates"] == str((tmp_path / "capture" / "plates").resolve())
    for camera in calibrated:
        plate = session.plate(camera.name)
        assert plate.shape == (camera.height, camera.width, 3)
        # The plate's markers moved with the undistortion, as the frames' did (PNG is lossless: 0.3 px).
        assert rig.marker_offsets(plate, session.camera(camera.name)).max() < 0.3
    # Scaled with the frames; a folder named explicitly is used instead of the capture's own.
    _write_plates(tmp_path / "elsewhere", calibrated)
    scaled = _ingest(tmp_path / "capture", tmp_path / "half.zarr", scale=0.5, plates=tmp_path / "elsewhere")
    assert scaled.plate("cam_a").shape == (48, 64, 3) and "elsewhere" in scaled.provenance["plates"]


def test_an_image_capture_keeps_its_plates_folder_out_of_its_cameras(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(["cam_a", "cam_b"])
    (tmp_path / "capture").mkdir()
    write_calibration(tmp_path / "capture" / "calibration.toml", cameras)
    rig.write_image_folders(tmp_path / "capture", cameras, 2)
    _write_plates(tmp_path / "capture" / "plates", cameras)
    assert detect_format(tmp_path / "capture") == "images"
    session = _ingest(tmp_path / "capture", tmp_path / "out.zarr")
    assert session.camera_names == ("cam_a", "cam_b") and session.plate("cam_b") is not None


@pytest.mark.parametrize(
    "problem, message",
    [
        ("missing", r"plates .*plates: no plate for camera 'cam_b'"),
        ("size", r"plate .*cam_b\.png: 64×48 pixels, but camera 'cam_b' is calibrated at 128×96"),
        ("folder", r"plates folder .*nowhere does not exist"),
    ],
)
def test_bad_plates_fail_clearly_and_leave_no_session(tmp_path: Path, problem: str, message: str) -> None:
    calibrated = rig.make_capture(tmp_path / "capture", frames=1)
    plates = tmp_path / "capture" / "plates"
    if problem == "missing":
        _write_plates(plates, calibrated[:1])
    elif problem == "size":
        _write_plates(plates, calibrated, {"cam_b": (64, 48)})
    with pytest.raises((FileNotFoundError, ValueError), match=message):
        _ingest(tmp_path / "capture", tmp_path / "out.zarr", plates=tmp_path / "nowhere" if problem == "folder" else None)
    assert rig.no_session_left(tmp_path / "out.zarr")


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared Pose2Sim demo not found at {POSE2SIM}")
def test_pose2sim_scene_calibration_names_match_its_videos(tmp_path: Path) -> None:
    # Calib_scene.toml names its cameras int_cam01_img…; the videos are cam01.mp4…: the file's name runs inside the camera's.
    with pytest.warns(UserWarning, match="decodes at 1080×1920"):
        recording = VideoReader(verify=False).open(POSE2SIM, POSE2SIM / "Calib_scene.toml")
    assert [camera.name for camera in recording.cameras] == ["int_cam01_img", "int_cam02_img", "int_cam03_img", "int_cam04_img"]
    assert recording.describe()["videos"]["int_cam03_img"].endswith("cam03.mp4")
    with pytest.raises(ValueError, match="'int_cam01_img', 'int_cam02_img' both match cam02.mp4"):
        VideoReader(verify=False, camera_map={"int_cam01_img": "cam02"}).open(POSE2SIM, POSE2SIM / "Calib_scene.toml")
    swapped = VideoReader(verify=False, camera_map={"int_cam01_img": "cam02", "int_cam02_img": "cam01"})
    with pytest.warns(UserWarning):
        assert swapped.open(POSE2SIM, POSE2SIM / "Calib_scene.toml").describe()["videos"]["int_cam01_img"].endswith("cam02.mp4")
    with pytest.raises(ValueError, match="camera_map names 'cam9', not calibrated cameras"):
        VideoReader(verify=False, camera_map={"cam9": "cam01"}).open(POSE2SIM, POSE2SIM / "Calib_scene.toml")


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared Pose2Sim demo not found at {POSE2SIM}")
def test_camera_map_order_pairs_the_calibrations_cameras_with_the_videos_in_name_order(tmp_path: Path) -> None:
    from mmcsplat.configuration.registry import default_registry

    reader = default_registry().create("reader", "videos", verify=False, camera_map="order")
    with pytest.warns(UserWarning, match="decodes at 1080×1920"):
        videos = reader.open(POSE2SIM, POSE2SIM / "Calib_scene.toml").describe()["videos"]
    assert {name: Path(path).name for name, path in videos.items()} == {f"int_cam0{i}_img": f"cam0{i}.mp4" for i in range(1, 5)}
    (tmp_path / "videos").mkdir()
    for i in (1, 2, 3):  # one video short of the calibration's four cameras
        (tmp_path / "videos" / f"cam0{i}.mp4").symlink_to(POSE2SIM / "videos" / f"cam0{i}.mp4")
    with pytest.raises(ValueError, match="calibration has 4 cameras and there are 3 videos"):
        reader.open(tmp_path, POSE2SIM / "Calib_scene.toml")
    with pytest.raises(ValueError, match="camera_map must be a table .* or 'order', got 'sorted'"):
        VideoReader(verify=False, camera_map="sorted").open(POSE2SIM, POSE2SIM / "Calib_scene.toml")


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared Pose2Sim demo not found at {POSE2SIM}")
@pytest.mark.parametrize("layout", ["pose2sim", "anipose", "freemocap", "per-camera folders"])
def test_project_layouts_are_recognised_without_flags(tmp_path: Path, layout: str) -> None:
    """Pose2Sim (calibration/Calib_*.toml, videos/), anipose (calibration/calibration.toml, videos-raw/),
    FreeMoCap (RECORDING_camera_calibration.toml beside synchronized_videos/) and one folder per camera
    (SOURCE/cam01/trial_cam01.mp4) ingest with no --calibration or --format."""
    source = tmp_path / "project"
    (source / "calibration").mkdir(parents=True)
    calibration = {"pose2sim": "calibration/Calib_qualisys.toml", "freemocap": "recording_camera_calibration.toml"}.get(
        layout, "calibration/calibration.toml")
    (source / calibration).symlink_to(POSE2SIM / "Calib_qualisys.toml")
    for video in sorted((POSE2SIM / "videos").glob("*.mp4")):
        if layout == "per-camera folders":
            (source / video.stem).mkdir()
            (source / video.stem / f"trial_{video.name}").symlink_to(video)
        else:
            folder = source / {"pose2sim": "videos", "freemocap": "synchronized_videos"}.get(layout, "videos-raw")
            folder.mkdir(exist_ok=True)
            (folder / video.name).symlink_to(video)
    out = tmp_path / "s.zarr"
    assert main(["ingest", str(source), str(out), "--frames", "0:2", "--scale", "0.125", "--no-progress", "--set", "verify=false"]) == 0
    reader = SessionReader(out)
    assert reader.camera_names == ("cam_01", "cam_02", "cam_03", "cam_04") and reader.num_frames == 2
    assert reader.provenance["reader"]["calibration"] == str(source / calibration)


def test_a_masks_folder_per_camera_is_ingested_as_the_captures_masks(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    cameras = rig.make_capture(source, frames=3)
    for camera in cameras:
        folder = source / "masks" / camera.name
        folder.mkdir(parents=True)
        for t in range(3):
            mask = np.zeros((camera.height, camera.width), np.uint8)
            mask[20 + 5 * t : 70, 30:100] = 255
            cv2.imwrite(str(folder / f"{t:04d}.png"), mask)
    session = _ingest(source, tmp_path / "out.zarr")
    assert all(session.has_source_mask(name) for name in session.camera_names)
    # Undistorted like the frames: the band's top edge moves down 5 rows a frame.
    tops = [np.flatnonzero(session.frame(t, "cam_a").mask.any(axis=1))[0] for t in range(3)]
    assert tops[1] - tops[0] == pytest.approx(5, abs=1) and tops[2] - tops[1] == pytest.approx(5, abs=1)
    (source / "masks" / "cam_b" / "0002.png").unlink()
    with pytest.raises(ValueError, match=r"masks: fewer mask images than the frames ingested \(cam_b: 2 of 3\)"):
        _ingest(source, tmp_path / "other.zarr")


def _caliscope_capture(tmp_path: Path, frames: list[int], moments: dict[int, list[int]]) -> Path:
    """Videos cam_0.mp4 and cam_1.mp4 as Caliscope records them, with ``frames`` each, and its timestamps.csv
    listing camera N at the sync indices ``moments[N]``."""
    tmp_path.mkdir()
    source, _ = _capture(tmp_path, ["cam_0", "cam_1"], "videos", frames, ["cam_0", "cam_1"])
    rows = ["sync_index,cam_id,frame_time"] + [f"{index},{cam},{100 + index / 30 + cam / 1000:.5f}"
                                                for cam, indices in moments.items() for index in indices]
    (source / "videos" / "timestamps.csv").write_text("\n".join(rows) + "\n")
    return source


def test_caliscope_timestamps_refuse_a_camera_that_missed_a_moment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # every moment in both cameras: frame k is one moment, the recording ingests
    source = _caliscope_capture(tmp_path / "whole", [3, 3], {0: [416, 417, 418], 1: [416, 417, 418]})
    assert _ingest(source, tmp_path / "whole.zarr").num_frames == 3
    # cam_1 missed moment 417: its second frame is moment 418, one behind cam_0's from there. Said before
    # any video is decoded (the verify pass takes minutes on a long recording).
    import mmcsplat.datasets.videos as videos

    decoded: list[Path] = []
    monkeypatch.setattr(videos, "decoded_frames", lambda path, count=videos.decoded_frames: decoded.append(path) or count(path))
    source = _caliscope_capture(tmp_path / "gap", [3, 2], {0: [416, 417, 418], 1: [416, 418]})
    with pytest.raises(InputError, match=r"timestamps.csv: camera cam_1 has no frame at sync index 417, "
                                         r"so from there frame k of its video is another moment.*pass --skip-missing"):
        _ingest(source, tmp_path / "gap.zarr")
    assert not (tmp_path / "gap.zarr").exists() and not decoded
    source = _caliscope_capture(tmp_path / "other", [3, 3], {0: [416, 417], 1: [416, 417]})
    with pytest.raises(InputError, match=r"2 frames of camera cam_0, but its video cam_0.mp4 holds 3: the timestamps are not this recording's"):
        _ingest(source, tmp_path / "other.zarr")
    source = _caliscope_capture(tmp_path / "twice", [2, 2], {0: [416, 416], 1: [416, 417]})
    decoded.clear()
    with pytest.raises(InputError, match=r"line 3: camera cam_0 has sync index 416 twice"):
        _ingest(source, tmp_path / "twice.zarr")
    assert not decoded
    timestamps = source / "videos" / "timestamps.csv"
    timestamps.write_text(timestamps.read_text().replace("416,0,", "416,0,x"))
    with pytest.raises(InputError, match=r"line 2: expected sync_index,cam_id,frame_time, whole numbers and then seconds"):
        _ingest(source, tmp_path / "unclocked.zarr")


def test_caliscope_moments_a_camera_missed_are_absent_with_skip_missing(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    whole = _ingest(_caliscope_capture(tmp_path / "whole", [3, 3], {0: [416, 417, 418], 1: [416, 417, 418]}), tmp_path / "whole.zarr")
    # cam_1 missed moment 417 and cam_0 moment 419: each video's frames are placed at their own moments
    source = _caliscope_capture(tmp_path / "gap", [3, 3], {0: [416, 417, 418], 1: [416, 418, 419]})
    with pytest.warns(UserWarning, match=r"of 4 moments, cam_0 lacks 1 \(first sync index 419\); cam_1 lacks 1 \(first sync index 417\)"):
        session = _ingest(source, tmp_path / "gap.zarr", skip_missing=True)
    assert session.num_frames == 4 and session.provenance["reader"]["timestamps"].endswith("videos/timestamps.csv")
    # the moments' times are the recording's clock (each the mean of its cameras'), not the frame rate's
    np.testing.assert_allclose(session.frame_times, [0, 1 / 30 - 5e-4, 2 / 30, 3 / 30 + 5e-4], atol=1e-5)
    assert session.present("cam_0").tolist() == [True, True, True, False]
    assert session.present("cam_1").tolist() == [True, False, True, True]
    # cam_1's second video frame is moment 418, the recording's third, beside cam_0's third video frame
    np.testing.assert_array_equal(session.frame(2, "cam_1").rgb, whole.frame(1, "cam_1").rgb)
    np.testing.assert_array_equal(session.frame(2, "cam_0").rgb, whole.frame(2, "cam_0").rgb)
    # a stride steps over the moments, not over each video's frames
    strided = _ingest(source, tmp_path / "strided.zarr", skip_missing=True, frames=slice(1, 4, 2))
    assert strided.present("cam_1").tolist() == [False, True] and strided.present("cam_0").tolist() == [True, False]
    np.testing.assert_array_equal(strided.frame(1, "cam_1").rgb, whole.frame(2, "cam_1").rgb)
    # the same from the command line
    assert main(["ingest", str(source), str(tmp_path / "cli.zarr"), "--skip-missing", "--no-progress"]) == 0
    assert SessionReader(tmp_path / "cli.zarr").present("cam_1").tolist() == [True, False, True, True]


def test_caliscope_keypoints_follow_each_video_frame_to_its_moment(tmp_path: Path) -> None:
    """2D keypoints are numbered by each camera's video frame (OpenPose's files, DeepLabCut's rows). Where a
    Caliscope camera missed a moment its video frame k is a later moment, and its keypoints go with it."""
    from mmcsplat.plugins.landmarks.openpose import MODELS, OpenPoseKeypoints

    # cam_1 missed moment 417: its video frame 1 is moment 418, the session's frame 2
    source = _caliscope_capture(tmp_path / "gap", [3, 2], {0: [416, 417, 418], 1: [416, 418]})
    with pytest.warns(UserWarning, match="those frames are absent"):
        session = _ingest(source, tmp_path / "gap.zarr", skip_missing=True)
    assert session.provenance["source_frame_offsets"] == {"cam_1": [[0, 0], [2, -1]]}
    assert session.source_frames("cam_0", [0, 1, 2]).tolist() == [0, 1, 2]
    assert session.source_frames("cam_1", [0, 1, 2]).tolist() == [0, -1, 1]
    assert session.source_frames("cam_1", [2]).tolist() == [1]
    # A person at a place of its own at each moment, detected in each camera's video frames of that moment.
    names = MODELS["BODY_25B"]
    body = np.random.default_rng(0).uniform(-0.25, 0.25, (len(names), 3))
    moments = [body + [0.08 * m, 0.0, 0.0] for m in range(3)]
    recorded = {camera.name: camera for camera in rig.ring_cameras(["cam_0", "cam_1"])}
    for name, video_moments in (("cam_0", [0, 1, 2]), ("cam_1", [0, 2])):
        (source / "pose" / name).mkdir(parents=True)
        for k, m in enumerate(video_moments):
            person = np.column_stack([recorded[name].project(moments[m]), np.full(len(names), 0.9)])
            (source / "pose" / name / f"{name}_{k:012d}_keypoints.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": person.ravel().tolist()}]}))
    seen = {o.camera: o for o in OpenPoseKeypoints(folder=str(source / "pose")).observations(session, [0, 1, 2])}
    for name, frames in (("cam_0", [0, 1, 2]), ("cam_1", [0, 2])):
        for t in frames:
            np.testing.assert_allclose(seen[name].pixels[t], session.camera(name).project(moments[t]), atol=0.5)
    assert not seen["cam_1"].confidence[1].any()  # the moment cam_1 missed holds none of its detections


def test_caliscope_video_whose_container_overstates_its_frames(tmp_path: Path) -> None:
    """A camera's dropped frame cut from a Matroska video: its container still states the duration's three
    frames, the timestamps two; the frames decoded are what counts."""
    import imageio_ffmpeg

    whole = _ingest(_caliscope_capture(tmp_path / "whole", [3, 3], {0: [416, 417, 418], 1: [416, 417, 418]}), tmp_path / "whole.zarr")
    source = _caliscope_capture(tmp_path / "cut", [3, 3], {0: [416, 417, 418], 1: [416, 418]})
    video = source / "videos" / "cam_1.mp4"
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(video), "-vf", "select=not(eq(n\\,1))", "-fps_mode", "passthrough",
                    "-c:v", "ffv1", str(video.with_suffix(".mkv"))], check=True)
    video.unlink()
    assert cv2.VideoCapture(str(video.with_suffix(".mkv"))).get(cv2.CAP_PROP_FRAME_COUNT) == 3
    with pytest.warns(UserWarning, match=r"cam_1 lacks 1 \(first sync index 417\)"):
        session = _ingest(source, tmp_path / "cut.zarr", skip_missing=True)
    assert session.present("cam_1").tolist() == [True, False, True]
    np.testing.assert_allclose(session.frame(2, "cam_1").rgb, whole.frame(2, "cam_1").rgb, atol=2)


def test_a_video_turned_by_its_rotation_tag_is_read_turned_and_said(tmp_path: Path) -> None:
    """A phone's 180° rotation tag keeps the frame size, so no size check tells it: frames are read turned (as
    OpenCV and players show them) and the reader says so."""
    import imageio_ffmpeg

    rig.make_capture(tmp_path / "capture", names=("c1", "c2", "c3"), frames=2)
    plain = _ingest(tmp_path / "capture", tmp_path / "plain.zarr")
    video = tmp_path / "capture" / "c2.mp4"
    tagged = video.with_name("tagged.mp4")
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-display_rotation", "180", "-i", str(video), "-c", "copy", str(tagged)],
                   check=True)
    tagged.replace(video)
    with pytest.warns(UserWarning, match=r"c2.mp4: its rotation tag turns its frames by 180°; they are read turned"):
        turned = _ingest(tmp_path / "capture", tmp_path / "turned.zarr")
    image, before = turned.frame(0, "c2").rgb.astype(float), plain.frame(0, "c2").rgb.astype(float)
    # The stored images are undistorted about an off-centre principal point, so the turn is close, not exact.
    assert np.abs(image - before[::-1, ::-1]).mean() < np.abs(image - before).mean() / 2  # measured 2.9 against 8.2


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared Pose2Sim demo not found at {POSE2SIM}")
def test_the_pose2sim_demos_videos_are_read_as_recorded() -> None:
    """No video of the demo carries a rotation tag: its calibration is of the frames as recorded (a copy of cam02
    tagged 180° once replaced the shared file, and nothing else noticed the camera read upside down)."""
    from mmcsplat.datasets.videos import probe

    assert {path.name: probe(path).rotation for path in sorted((POSE2SIM / "videos").glob("*.mp4"))} == {
        "cam01.mp4": 0, "cam02.mp4": 0, "cam03.mp4": 0, "cam04.mp4": 0}
