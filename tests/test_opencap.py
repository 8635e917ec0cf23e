"""OpenCap sessions: the per-camera calibration pickles (read without running them), the session's
synchronised videos and trials, its markers' axes, and ingest beside the same cameras in a TOML."""

from __future__ import annotations

import logging
import pickle
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import rig_fixtures as rig
from test_easymocap_calibration import assert_same_cameras

from mmcsplat.datasets.rig import find_calibration
from mmcsplat.pipeline.capture_session import joints_file, keypoint_folder, keypoint_source
from mmcsplat.pipeline.ingest import detect_format, ingest
from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugins.landmarks.files import TrcLandmarks
from mmcsplat.plugins.landmarks.opencap import BODY_25, OpencapKeypoints
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import format_units, read_rig, write_calibration
from mmcsplat.storage.landmark_formats import TRC_AXES, read_trc, write_trc
from mmcsplat.storage.opencap_calibration import OPENCAP_CALIBRATION, TRC_PLACEMENTS, opencap_convention
from mmcsplat.storage.opencap_session import opencap_markers, opencap_videos

#: Folder names in text order unlike number order (Cam10 after Cam2).
NAMES = ("Cam0", "Cam10", "Cam2")
TRIAL = "squat"


def calibration_content(camera: Camera) -> dict[str, np.ndarray]:
    """``camera`` (metres) as OpenCap pickles it: translation in millimetres, size as [[height], [width]]."""
    return {"intrinsicMat": camera.K, "distortion": camera.distortion.reshape(1, 5), "imageSize": np.array([[camera.height], [camera.width]], float),
            "rotation": camera.R, "translation": camera.t.reshape(3, 1) * 1000, "rotation_EulerAngles": camera.rvec.reshape(3, 1)}


def write_session(folder: Path, cameras: list[Camera], trials: dict[str, int] | None = None) -> Path:
    """An OpenCap session: each camera's pickle in ``Videos/<name>/`` and, for each trial, its synchronised
    video of that many frames; returns the first camera's pickle."""
    for camera in cameras:
        (folder / "Videos" / camera.name).mkdir(parents=True, exist_ok=True)
        (folder / "Videos" / camera.name / OPENCAP_CALIBRATION).write_bytes(pickle.dumps(calibration_content(camera)))
        for trial, frames in (trials or {}).items():
            rig.write_videos(folder / "Videos" / camera.name / "InputMedia" / trial, [camera], frames, stems=[f"{trial}_sync"])
    return folder / "Videos" / cameras[0].name / OPENCAP_CALIBRATION


def test_the_rig_is_every_camera_folder_in_number_order_in_metres(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(NAMES, width=96, height=128)
    first = write_session(tmp_path, cameras)
    for path in (first, tmp_path / "Videos" / "Cam2" / OPENCAP_CALIBRATION):  # any camera's file stands for the rig
        read = read_rig(path)
        assert read.units == "mm"
        assert_same_cameras(read.cameras, [cameras[0], cameras[2], cameras[1]])
    assert [c.name for c in read_rig(first, cameras=["Cam2", "Cam10"]).cameras] == ["Cam2", "Cam10"]
    assert read_rig(first, units="m").units == format_units(first) == "mm"  # OpenCap's unit, whatever --units says
    for given in (None, tmp_path, tmp_path / "Videos", first):
        assert find_calibration(tmp_path, given) == first


def test_a_pickle_that_names_anything_but_arrays_is_refused_unrun(tmp_path: Path) -> None:
    first = write_session(tmp_path, rig.ring_cameras(NAMES[:2]))
    content = pickle.loads(first.read_bytes())
    first.write_bytes(pickle.dumps({**content, "rotation": Path("/etc/passwd")}))
    with pytest.raises(InputError, match=rf"calibration {first}: not OpenCap's pickle of arrays \(it refers to pathlib\.\w*Path\)"):
        read_rig(first)


@pytest.mark.parametrize(("edit", "message"), [
    ({"translation": None}, "missing translation"),
    ({"distortion": np.zeros((1, 4))}, "distortion must hold 5 numbers, got 4"),
    ({"intrinsicMat": np.full((3, 3), np.nan)}, "intrinsicMat is not finite"),
])
def test_bad_pickles_are_refused_naming_the_file_and_key(tmp_path: Path, edit: dict, message: str) -> None:
    write_session(tmp_path, rig.ring_cameras(NAMES[:2]))
    broken = tmp_path / "Videos" / "Cam10" / OPENCAP_CALIBRATION
    content = {key: value for key, value in {**pickle.loads(broken.read_bytes()), **edit}.items() if value is not None}
    broken.write_bytes(pickle.dumps(content))
    with pytest.raises(InputError, match=rf"calibration {broken}: {message}"):
        read_rig(tmp_path / "Videos" / "Cam0" / OPENCAP_CALIBRATION)
    broken.write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(InputError, match=rf"calibration {broken}: holds a list, not OpenCap's dict of arrays"):
        read_rig(broken)


def test_the_session_gives_one_trials_synchronised_videos(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(NAMES[:2])
    write_session(tmp_path, cameras, {TRIAL: 3})
    names = [c.name for c in cameras]
    assert opencap_videos(tmp_path, names, None) == {name: tmp_path / "Videos" / name / "InputMedia" / TRIAL / f"{TRIAL}_sync.mp4" for name in names}
    rig.write_videos(tmp_path / "Videos" / "Cam0" / "InputMedia" / "neutral", cameras[:1], 2, stems=["neutral_sync"])
    with pytest.raises(InputError, match=rf"OpenCap session {tmp_path}: trials neutral, squat; choose one with --reader-set trial=NAME"):
        opencap_videos(tmp_path, names, None)
    assert opencap_videos(tmp_path, names, TRIAL)["Cam10"].parent.name == TRIAL
    with pytest.raises(MissingFileError, match=r"Videos/Cam10/InputMedia/neutral/neutral_sync.mp4 \(trial 'neutral' lacks camera Cam10\); "
                                               r"leave it out with --cameras"):
        opencap_videos(tmp_path, names, "neutral")
    with pytest.raises(MissingFileError, match=r"no synchronised video of trial 'walk' \(trials: neutral, squat\)"):
        opencap_videos(tmp_path, names, "walk")


def test_ingest_reads_the_session_as_the_same_cameras_in_a_toml(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(NAMES[:2])
    session = tmp_path / "OpenCapData_1"
    write_session(session, cameras, {TRIAL: 3})
    write_calibration(tmp_path / "calibration.toml", cameras)
    assert detect_format(session) == "videos"
    from_pickles = ingest(session, tmp_path / "opencap.zarr", progress=False)
    from_toml = ingest(session, tmp_path / "toml.zarr", calibration=tmp_path / "calibration.toml", progress=False)
    assert from_pickles.provenance["reader"]["units"] == "mm"
    assert_same_cameras([from_pickles.camera(n) for n in NAMES[:2]], [from_toml.camera(n) for n in NAMES[:2]])
    for name in NAMES[:2]:
        np.testing.assert_array_equal(from_pickles.frame(2, name).rgb, from_toml.frame(2, name).rgb)


def camera_held(up_in_board: np.ndarray) -> Camera:
    """A camera 3 m from the board's origin, looking at it level, its image up along ``up_in_board``."""
    up = np.asarray(up_in_board, float) / np.linalg.norm(up_in_board)
    forward = np.cross(up, [1.0, 0, 0]) if abs(up[0]) < 0.9 else np.cross(up, [0, 1.0, 0])
    forward /= np.linalg.norm(forward)
    R = np.stack([np.cross(-up, forward), -up, forward])  # rows: the camera's x, y (image down), z (forward) in the board's frame
    return Camera("Cam0", 720, 1280, [[900, 0, 360], [0, 900, 640], [0, 0, 1]], R, -R @ (-3 * forward))


@pytest.mark.parametrize("placement", TRC_PLACEMENTS)
def test_the_markers_axes_follow_the_boards_placement(tmp_path: Path, placement: str) -> None:
    up = TRC_AXES[placement][:, 1]  # the TRC's Y, in the board's frame
    tilted = camera_held(up + np.array([0.3, 0.2, 0.1]) * (1 - np.abs(up)))
    assert opencap_convention([camera_held(up), tilted], "here") == placement
    world = np.random.default_rng(0).normal(size=(4, 2, 3))
    world[1, 0, 2] = np.nan  # a missing coordinate stays its own
    write_trc(tmp_path / "m.trc", ("RKnee", "LKnee"), np.arange(4) / 60, world, 60, convention=placement)
    read = read_trc(tmp_path / "m.trc", placement).positions
    np.testing.assert_allclose(read, world, atol=1e-6)
    assert np.isnan(read).sum() == 1
    file_up = read_trc(tmp_path / "m.trc", "none").positions[..., 1]
    axis = int(np.abs(up).argmax())  # the TRC's Y is the world's up, the board's axis that is
    np.testing.assert_allclose(file_up, world[..., axis] * up[axis], atol=1e-6)


def test_cameras_along_no_axis_of_the_board_are_refused() -> None:
    with pytest.raises(InputError, match=r"here: the cameras' image up is along no axis of the calibration board"):
        opencap_convention([camera_held(np.array([1.0, 1.0, 1.0]) / np.sqrt(3))], "here")


def test_run_finds_the_trials_markers_and_reads_them_in_opencaps_axes(tmp_path: Path) -> None:
    """The session's cameras (image up along the board's −z: a board on the floor) choose the markers' axes;
    a session calibrated otherwise keeps Pose2Sim's."""
    session = tmp_path / "OpenCapData_1"
    board = np.diag([1.0, -1.0, -1.0])  # the ring's world turned so that the floor's up is the board's −z
    cameras = [Camera(c.name, c.width, c.height, c.K, c.R @ board, c.t, c.distortion) for c in rig.ring_cameras(NAMES[:2])]
    write_session(session, cameras, {TRIAL: 2})
    assert joints_file(session, None) is None
    world = np.array([[[0.1, 0.2, -0.9]], [[0.1, 0.25, -0.9]]])  # 0.9 m over the floor
    (session / "MarkerData").mkdir()
    write_trc(session / "MarkerData" / f"{TRIAL}.trc", ("Neck",), np.arange(2) / 30, world, 30, convention="opencap-ground")
    assert joints_file(session, None) == opencap_markers(session, TRIAL) == (session / "MarkerData" / f"{TRIAL}.trc").resolve()
    stored = ingest(session, tmp_path / "s.zarr", progress=False)
    markers = TrcLandmarks(path=str(session / "MarkerData" / f"{TRIAL}.trc"))
    assert markers.resolved_convention(stored) == "opencap-ground"
    np.testing.assert_allclose(markers.read(stored, [0, 1]).positions, world, atol=1e-6)
    write_calibration(tmp_path / "calibration.toml", cameras)
    other = ingest(session, tmp_path / "toml.zarr", calibration=tmp_path / "calibration.toml", progress=False)
    assert markers.resolved_convention(other) == "pose2sim"


def test_markers_lifted_by_an_unknown_height_are_not_taken(tmp_path: Path) -> None:
    """A board on a wall (the ring's images' up along the board's −y): OpenCap lifts the markers by the
    board's height, which its download does not keep; nor are they taken to place the phones' keypoints."""
    wall = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # board y = −world z
    cameras = [Camera(c.name, c.width, c.height, c.K, c.R @ wall.T, c.t, c.distortion) for c in rig.ring_cameras(NAMES[:2])]
    write_session(tmp_path, cameras, {TRIAL: 2})
    (tmp_path / "MarkerData").mkdir()
    write_trc(tmp_path / "MarkerData" / f"{TRIAL}.trc", ("Neck",), np.arange(2) / 30, np.zeros((2, 1, 3)), 30, convention="opencap-wall")
    with pytest.warns(UserWarning, match=r"not taken as the joints: the session was calibrated on a board on a wall \(opencap-wall\)"):
        assert joints_file(tmp_path, None) is None
    for camera in cameras:
        (tmp_path / "Videos" / camera.name / "OutputPkl").mkdir()
        (tmp_path / "Videos" / camera.name / "OutputPkl" / f"{TRIAL}_keypoints.pkl").write_bytes(pickle.dumps([[]] * 2))
    assert keypoint_folder(tmp_path, None) is None


def test_opencaps_trc_header_is_read(tmp_path: Path) -> None:
    """OpenCap writes a space, not a tab, after PathFileType."""
    write_trc(tmp_path / "m.trc", ("Neck",), np.arange(2) / 60, np.zeros((2, 1, 3)), 60)
    text = (tmp_path / "m.trc").read_text()
    (tmp_path / "m.trc").write_text(text.replace("PathFileType\t4", "PathFileType  4", 1))
    assert read_trc(tmp_path / "m.trc").names == ("Neck",)


def test_a_session_of_every_other_frame_keeps_the_captures_rate_for_its_markers(tmp_path: Path) -> None:
    """Ingested with a step, the session runs at half the rate; its markers' rows are still the capture's frames."""
    cameras = rig.ring_cameras(NAMES[:2])
    write_session(tmp_path, cameras, {TRIAL: 4})
    stored = ingest(tmp_path, tmp_path / "s.zarr", frames=slice(0, 4, 2), progress=False)
    assert (stored.fps, stored.capture_fps) == (15.0, 30.0)
    world = np.arange(12, dtype=float).reshape(4, 1, 3)
    write_trc(tmp_path / "m.trc", ("Neck",), np.arange(4) / 30, world, 30, convention="opencap-ground")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read = TrcLandmarks(path=str(tmp_path / "m.trc"), convention="opencap-ground").read(stored, [0, 1])
    np.testing.assert_allclose(read.positions, world[[0, 2]], atol=1e-6)


#: The joints of the markers the keypoint tests move, by BODY_25's names.
MOVING = ("Neck", "RShoulder", "LShoulder", "RHip", "LHip", "RKnee", "LKnee", "RWrist")
STARTS = {"Cam0": 3, "Cam10": 7, "Cam2": 0}


def ground_ring(names: Sequence[str]) -> list[Camera]:
    """The ring's cameras in the frame of a board lying on the floor (its z down)."""
    board = np.diag([1.0, -1.0, -1.0])
    return [Camera(c.name, c.width, c.height, c.K, c.R @ board, c.t, c.distortion) for c in rig.ring_cameras(names)]


def keypoint_session(folder: Path, frames: int = 8) -> np.ndarray:
    """An OpenCap session of three phones whose recordings are twice the synchronised videos' size and start
    :data:`STARTS` frames before them, with their detections (a bystander in every frame) and the trial's
    markers; returns the markers' world positions [T, len(MOVING), 3]."""
    cameras = ground_ring(NAMES)
    write_session(folder, cameras, {TRIAL: frames})
    phase = 0.9 * np.arange(frames)[:, None] + np.arange(len(MOVING))[None]  # [T, J]: every joint swings its own way
    rest = np.array([[0.0, 0.05 * i - 0.2, -0.4 - 0.05 * i] for i in range(len(MOVING))])
    world = rest + 0.04 * np.stack([np.sin(phase), np.cos(0.8 * phase), np.zeros_like(phase)], axis=-1)
    for camera in cameras:
        recording = Camera(camera.name, 2 * camera.width, 2 * camera.height, np.diag([2.0, 2.0, 1.0]) @ camera.K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]],
                           camera.R, camera.t, camera.distortion)
        (folder / "Videos" / camera.name / OPENCAP_CALIBRATION).write_bytes(pickle.dumps(calibration_content(recording)))
        detections = []
        for k in range(-STARTS[camera.name], frames + 2):
            subject = np.zeros((25, 3))
            if 0 <= k < frames:
                subject[[BODY_25.index(name) for name in MOVING]] = np.column_stack([recording.project(world[k]), np.full(len(MOVING), 0.9)])
            else:  # before and after the cut: someone else
                subject[:, :2], subject[:, 2] = 50 + 7 * abs(k), 0.9
            bystander = np.column_stack([np.full((25, 2), 5.0), np.full(25, 0.9)])
            detections.append([{"person_id": [i], "pose_keypoints_2d": person.ravel().tolist()} for i, person in enumerate((bystander, subject))])
        (folder / "Videos" / camera.name / "OutputPkl").mkdir()
        (folder / "Videos" / camera.name / "OutputPkl" / f"{TRIAL}_keypoints.pkl").write_bytes(pickle.dumps(detections))
    (folder / "MarkerData").mkdir()
    write_trc(folder / "MarkerData" / f"{TRIAL}.trc", MOVING, np.arange(frames) / 30, world, 30, convention="opencap-ground")
    return world


def test_the_phones_keypoints_are_placed_by_the_markers_and_triangulate_to_them(tmp_path: Path, caplog) -> None:
    session = tmp_path / "OpenCapData_1"
    world = keypoint_session(session)
    assert keypoint_folder(session, None) == session.resolve()
    assert keypoint_source(session) == {"name": "opencap", "path": str(session)}
    stored = ingest(session, tmp_path / "s.zarr", progress=False)
    with caplog.at_level(logging.INFO, logger="mmcsplat.plugins.landmarks.opencap"):
        read = OpencapKeypoints(path=str(session)).read(stored, list(range(stored.num_frames)))
    for name, start in STARTS.items():
        assert f"{name}/OutputPkl/{TRIAL}_keypoints.pkl: the synchronised video starts at its recording's frame {start} " in caplog.text
    np.testing.assert_allclose(read.positions[:, [read.names.index(name) for name in MOVING]], world, atol=2e-3)


def test_keypoints_that_no_start_places_near_the_markers_are_refused(tmp_path: Path) -> None:
    keypoint_session(tmp_path)
    stored = ingest(tmp_path, tmp_path / "s.zarr", progress=False)
    markers = tmp_path / "MarkerData" / f"{TRIAL}.trc"
    data = read_trc(markers, "opencap-ground")
    write_trc(markers, data.names, data.times, data.positions + [0.0, 0.0, -0.5], 30, convention="opencap-ground")  # half a metre up
    with pytest.raises(InputError, match=r"Cam0/OutputPkl/squat_keypoints.pkl: no start in its recording puts its detections within 10 px"):
        OpencapKeypoints(path=str(tmp_path)).read(stored, [0])
    markers.unlink()
    with pytest.raises(MissingFileError, match=r"no MarkerData/squat.trc, by which OpenCap's keypoints of trial 'squat' are placed"):
        OpencapKeypoints(path=str(tmp_path)).read(stored, [0])


def test_a_study_names_the_trial_of_a_session_with_several(tmp_path: Path, monkeypatch) -> None:
    """A study's capture table takes the reader's options as run's --reader-set does: the trial chooses the videos
    and the markers scored against; without it a session of several trials is refused, as by run."""
    from mmcsplat.studies.sessions import prepare_session
    from mmcsplat.studies.spec import StudyError, expand, load_study

    session = tmp_path / "OpenCapData_1"
    board = np.diag([1.0, -1.0, -1.0])
    cameras = [Camera(c.name, c.width, c.height, c.K, c.R @ board, c.t, c.distortion) for c in rig.ring_cameras(NAMES[:2])]
    write_session(session, cameras, {TRIAL: 2, "walk": 2})
    (session / "MarkerData").mkdir()
    for trial in (TRIAL, "walk"):
        write_trc(session / "MarkerData" / f"{trial}.trc", ("Neck",), np.arange(2) / 30, np.zeros((2, 1, 3)), 30, convention="opencap-ground")

    def study(capture: str) -> Path:
        path = tmp_path / "study.toml"
        path.write_text(f'[study]\nname = "trials"\n\n[sessions.phones.capture]\n{capture}\n\n[[variant]]\nname = "fit"\nconfig = "paper-masked"\n')
        return path

    with pytest.raises(StudyError, match=r"\[sessions.phones\] capture: OpenCap session .*: trials squat, walk; choose one"):
        load_study(study(f'path = "{session}"'))
    chosen = load_study(study(f'path = "{session}"\nreader = {{ trial = "walk" }}')).sessions[0].capture
    assert chosen["reader"] == {"trial": "walk"} and chosen["joints"] == str((session / "MarkerData" / "walk.trc").resolve())
    with pytest.raises(StudyError, match="capture: .*fps"):  # an option the reader does not take, before anything runs
        load_study(study(f'path = "{session}"\nreader = {{ trial = "walk", fps = 30 }}'))
    with pytest.raises(StudyError, match="capture reader must be a table"):
        load_study(study(f'path = "{session}"\nreader = "walk"'))
    cell = expand(load_study(study(f'path = "{session}"\nreader = {{ trial = "walk" }}')), tmp_path / "out")[0]
    assert cell.plan.identity["capture"]["reader"] == {"trial": "walk"}
    made = {}
    monkeypatch.setattr("mmcsplat.pipeline.capture_session.prepare_capture_session",
                        lambda capture, partial, **kwargs: (partial.mkdir(parents=True), made.update(kwargs)))
    prepare_session(cell.plan, progress=False)
    assert made["reader_options"] == {"trial": "walk"}
