"""2D keypoints (OpenPose JSON): triangulated into landmarks in the session's cameras, and drawn as skeleton
masks for captures without plates or a segmentation model — on keypoints made by projecting known joints,
and on the real Pose2Sim demo against its triangulated joints."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from fitting_scene import write_session

from mmcsplat.cli import main
from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.landmarks.openpose import MODELS, read_people
from mmcsplat.plugins.landmarks.subject import choose_subject
from mmcsplat.plugins.segmenters.keypoints import skeleton_mask, torso_mask
from mmcsplat.scene.human_skeleton import openpose_name
from mmcsplat.storage.landmark_formats import read_trc
from mmcsplat.storage.session import SessionReader, SessionUpdater

POSE2SIM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"
FRAMES = 3
#: A stick figure 60 cm tall (these coordinates doubled) around the fitting scene's origin, in BODY_25B names (z up).
FIGURE = {"Neck": (0, 0, 0.12), "Head": (0, 0, 0.17), "Nose": (0.02, 0, 0.15), "LShoulder": (0, 0.05, 0.11), "RShoulder": (0, -0.05, 0.11),
          "LElbow": (0, 0.09, 0.05), "RElbow": (0, -0.09, 0.05), "LWrist": (0, 0.1, 0.0), "RWrist": (0, -0.1, 0.0), "LHip": (0, 0.03, -0.03),
          "RHip": (0, -0.03, -0.03), "LKnee": (0, 0.04, -0.09), "RKnee": (0, -0.04, -0.09), "LAnkle": (0, 0.04, -0.15), "RAnkle": (0, -0.04, -0.15)}


def figure_at(t: int) -> np.ndarray:
    """[25, 3] BODY_25B joints at frame t (the figure slides 1 cm per frame; keypoints it lacks are NaN)."""
    joints = np.full((25, 3), np.nan)
    for name, point in FIGURE.items():
        joints[MODELS["BODY_25B"].index(name)] = np.multiply(point, 2.0) + (0.01 * t, 0.0, 0.0)
    return joints


#: (joint, frame) the detector files of the FreeMoCap and Caliscope tests leave out, as a tracker leaves out what it missed.
UNDETECTED = ("Nose", 1)


def figure_named(names: tuple[str, ...]) -> np.ndarray:
    """[FRAMES, len(names), 3] the figure's joints at the keypoints ``names`` (a detector's, renamed as OpenPose's), NaN
    where the figure has none and at :data:`UNDETECTED`."""
    converted = [openpose_name(name) for name in names]
    result = np.full((FRAMES, len(names), 3), np.nan)
    for t in range(FRAMES):
        for joint in FIGURE:
            if joint in converted and (joint, t) != UNDETECTED:
                result[t, converted.index(joint)] = figure_at(t)[MODELS["BODY_25B"].index(joint)]
    return result


def figure_in(model: str, t: int) -> np.ndarray:
    """[25, 3] the figure's joints at frame t in ``model``'s order; BODY_25's MidHip a detector's estimate of the
    hips' midpoint (5 mm below it)."""
    joints = figure_at(t)
    named = {name: joints[MODELS["BODY_25B"].index(name)] for name in MODELS["BODY_25B"]}
    named["MidHip"] = (named["LHip"] + named["RHip"]) / 2 - (0.0, 0.0, 0.005)
    return np.array([named.get(name, np.full(3, np.nan)) for name in MODELS[model]])


def write_openpose(folder: Path, session: SessionReader, model: str = "BODY_25B") -> None:
    """One folder per camera of OpenPose files of ``model``: the figure's projection (confidence 0.9), and a
    fainter second person (confidence 0.2) the source must not take."""
    for camera in session.cameras:
        out = folder / f"{camera.name.replace('_', '')}_json"
        out.mkdir(parents=True)
        for t in range(FRAMES):
            joints = figure_in(model, t)
            known = np.all(np.isfinite(joints), axis=1)
            pixels = camera.project(np.where(known[:, None], joints, 0.0))
            person = np.column_stack([pixels, np.where(known, 0.9, 0.0)])
            stranger = np.column_stack([pixels + 20.0, np.where(known, 0.2, 0.0)])
            people = [{"pose_keypoints_2d": stranger.ravel().tolist()}, {"pose_keypoints_2d": person.ravel().tolist()}]
            (out / f"{camera.name}_{t:012d}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": people}))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("keypoints")
    session = write_session(root / "session.zarr", frames=FRAMES, zoom=4)
    write_openpose(root / "pose_2d", SessionReader(session))
    return session, root / "pose_2d"


def test_keypoints_triangulate_to_the_joints_they_came_from(scene):
    session, folder = scene
    source = default_registry().create("landmarks", "openpose", folder=str(folder))
    landmarks = source.read(SessionReader(session), range(FRAMES))
    assert landmarks.names == MODELS["BODY_25B"] and landmarks.positions.shape == (FRAMES, 25, 3)
    for t in range(FRAMES):
        np.testing.assert_allclose(landmarks.positions[t], figure_at(t), atol=1e-6)  # NaN where undetected, as the truth
    observed = source.observations(SessionReader(session), range(FRAMES))
    assert [o.camera for o in observed] == list(SessionReader(session).camera_names)
    assert observed[0].confidence.max() == pytest.approx(0.9)  # the confident person, not the stranger


def test_openposes_own_body_25_is_told_from_body_25b_by_its_midhip(scene, tmp_path):
    """OpenPose's default model, BODY_25, has as many keypoints as Pose2Sim's BODY_25B in another order: read as
    BODY_25B its knees would be ankles. The source tells them apart by keypoint 8 (BODY_25's MidHip, between
    its hips), unless the model is named; too few detections to tell by are read as BODY_25B, with a warning."""
    session, b_folder = scene
    reader = SessionReader(session)
    folder = tmp_path / "body_25"
    write_openpose(folder, reader, "BODY_25")
    landmarks = default_registry().create("landmarks", "openpose", folder=str(folder)).read(reader, range(FRAMES))
    assert landmarks.names == MODELS["BODY_25"]
    for t in range(FRAMES):
        np.testing.assert_allclose(landmarks.positions[t], figure_in("BODY_25", t), atol=1e-6)
    assert default_registry().create("landmarks", "openpose", folder=str(b_folder)).read(reader, range(FRAMES)).names == MODELS["BODY_25B"]
    named = default_registry().create("landmarks", "openpose", folder=str(folder), model="BODY_25B").read(reader, range(FRAMES))
    assert named.names == MODELS["BODY_25B"]  # as told, wrong as it is
    # The whole folder decides, not the frames read: one frame read is read as the folder's model.
    assert default_registry().create("landmarks", "openpose", folder=str(folder)).read(reader, range(1)).names == MODELS["BODY_25"]
    one_frame = tmp_path / "one_frame"
    for camera in folder.iterdir():
        (one_frame / camera.name).mkdir(parents=True)
        first = sorted(camera.glob("*.json"))[0]
        (one_frame / camera.name / first.name).write_bytes(first.read_bytes())
    with pytest.warns(UserWarning, match="too few confident detections to tell BODY_25 from BODY_25B: read as BODY_25B"):
        few = default_registry().create("landmarks", "openpose", folder=str(one_frame)).read(reader, range(1))
    assert few.names == MODELS["BODY_25B"]


def test_the_subject_is_the_person_the_cameras_agree_on_not_the_most_confident(scene, tmp_path):
    """A bystander detected more confidently than the subject (a parent beside an infant), in one camera the
    only person seen: the subject is the person nearest where the cameras look, followed from frame to frame,
    and the camera that sees only the bystander gives no detections that frame."""
    reader = SessionReader(scene[0])
    folder = tmp_path / "pose_2d"
    bystander_at = np.array([0.0, 0.35, 0.0])
    detected = [[] for _ in reader.cameras]
    for index, camera in enumerate(reader.cameras):
        out = folder / camera.name
        out.mkdir(parents=True)
        for t in range(FRAMES):
            joints = figure_at(t)
            known = np.all(np.isfinite(joints), axis=1)
            people = []
            for offset, confidence in ((bystander_at, 0.9), (np.zeros(3), 0.5)):
                pixels = camera.project(np.where(known[:, None], joints + offset, 0.0))
                people.append({"pose_keypoints_2d": np.column_stack([pixels, np.where(known, confidence, 0.0)]).ravel().tolist()})
            if index == 0 and t == 1:
                people = people[:1]  # the subject hidden from this camera: only the bystander
            if index == 1 and t == 2:  # the subject split in two detections, its upper body and its legs
                whole = np.array(people[1]["pose_keypoints_2d"]).reshape(-1, 3)
                legs = np.isin(np.arange(len(whole)), [MODELS["BODY_25B"].index(n) for n in ("LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle")])
                people[1:] = [{"pose_keypoints_2d": np.where(part[:, None], whole, 0.0).ravel().tolist()} for part in (~legs, legs)]
            (out / f"{camera.name}.{t:04d}.json").write_text(json.dumps({"people": people}))
            detected[index].append(np.array([p["pose_keypoints_2d"] for p in people]).reshape(len(people), -1, 3))
    source = default_registry().create("landmarks", "openpose", folder=str(folder))
    observed = source.observations(reader, range(FRAMES))
    assert observed[0].confidence[1].max() == 0.0  # not the bystander
    assert all(o.confidence[t].max() == pytest.approx(0.5) for o in observed for t in range(FRAMES) if (o, t) != (observed[0], 1))
    assert (observed[1].confidence[2] > 0).sum() == len(FIGURE)  # the split subject joined again
    landmarks = source.read(reader, range(FRAMES))
    for t in range(FRAMES):
        np.testing.assert_allclose(landmarks.positions[t], figure_at(t), atol=1e-6)
    # a held-out camera does not judge: it takes the detection nearest the subject the others found
    judges = [False] + [True] * (len(reader.cameras) - 1)
    chosen = choose_subject(detected, reader.cameras, 0.3, judges)
    assert chosen[0] == [(1,), (), (1,)] and chosen[1][:2] == [(1,), (1,)] and sorted(chosen[1][2]) == [1, 2] and all(c == [(1,), (1,), (1,)] for c in chosen[2:])
    # nor decides for them: where it is the only other camera that sees anyone, the one camera left takes its
    # most confident person (the bystander), as it would alone
    alone = [[frames[0]] if index < 2 else [frames[0][:0]] for index, frames in enumerate(detected)]
    assert [c[0] for c in choose_subject(alone, reader.cameras, 0.3)][:2] == [(1,), (1,)]
    assert [c[0] for c in choose_subject(alone, reader.cameras, 0.3, judges)][:2] == [(0,), (0,)]


def test_skeleton_masks_cover_the_figure(scene, tmp_path):
    import shutil

    session, folder = scene
    copy = tmp_path / "session.zarr"
    shutil.copytree(session, copy)
    assert main(["segment", str(copy), "--segmenter", "keypoints", "--set", f'source={{name="openpose", folder="{folder}"}}', "--no-progress"]) == 0
    reader = SessionReader(copy)
    for camera in reader.cameras:
        mask = reader.frame(1, camera.name).mask
        joints = figure_at(1)
        inside = camera.project(joints[np.all(np.isfinite(joints), axis=1)]).round().astype(int)
        inside = inside[(inside[:, 0] >= 0) & (inside[:, 0] < camera.width) & (inside[:, 1] >= 0) & (inside[:, 1] < camera.height)]
        assert mask[inside[:, 1], inside[:, 0]].all(), camera.name
        assert 0.005 < mask.mean() < 0.5
    assert main(["segment", str(copy), "--segmenter", "keypoints", "--set", "refine=plate",
                 "--set", f'source={{name="openpose", folder="{folder}"}}', "--no-progress"]) == 2  # no plate yet: said so


def test_a_plate_holding_the_still_subject_leaves_the_torso_in_the_refined_mask(scene, tmp_path):
    """An estimated plate may keep a trunk that barely moved: refined against a plate equal to the frame,
    nothing differs, and the torso's polygon alone is left as the mask."""
    import shutil

    session, folder = scene
    copy = tmp_path / "session.zarr"
    shutil.copytree(session, copy)
    reader = SessionReader(copy)
    with SessionUpdater(copy) as updater:
        for camera in reader.camera_names:
            updater.write_plate(camera, reader.frame(1, camera).rgb, {"kind": "estimated"})

    def segment(torso: bool) -> int:
        return main(["segment", str(copy), "--segmenter", "keypoints", "--set", "refine=plate", "--set", f"torso={str(torso).lower()}",
                     "--set", f'source={{name="openpose", folder="{folder}"}}', "--no-progress"])

    assert segment(False) == 2  # every mask empty: refused as implausible, nothing written
    assert segment(True) == 0
    joints = figure_at(1)
    corners = joints[[MODELS["BODY_25B"].index(name) for name in ("LShoulder", "RShoulder", "RHip", "LHip")]]
    for camera in reader.cameras:
        mask = SessionReader(copy).frame(1, camera.name).mask
        centre = camera.project(corners.mean(axis=0, keepdims=True)).round().astype(int)[0]
        wrist = camera.project(joints[[MODELS["BODY_25B"].index("LWrist")]]).round().astype(int)[0]
        assert mask[centre[1], centre[0]] and not mask[wrist[1], wrist[0]], camera.name


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared real data not found at {POSE2SIM}")
def test_pose2sim_keypoints_triangulate_near_its_joints(tmp_path):
    session = tmp_path / "p2s.zarr"
    assert main(["ingest", str(POSE2SIM), str(session), "--calibration", str(POSE2SIM / "Calib_qualisys.toml"), "--frames", "0:3",
                 "--scale", "0.25", "--no-progress"]) == 0
    reader = SessionReader(session)
    landmarks = default_registry().create("landmarks", "openpose", folder=str(POSE2SIM / "pose_2d")).read(reader, range(3))
    joints = read_trc(POSE2SIM / "joints_3d.trc")
    errors = {name: np.linalg.norm(landmarks.positions[:, landmarks.names.index(name)] - joints.positions[:3, j], axis=-1)
              for j, name in enumerate(joints.names) if name in landmarks.names}
    assert len(errors) == 21
    # Most joints agree within 2 cm (measured over the first 3 frames: 4–9 mm); hips, shoulders and a few
    # others differ by 3–7 cm, as Pose2Sim filters its joints and triangulates with outlier rejection.
    assert np.median([np.median(e) for e in errors.values()]) < 0.02
    assert sum(np.median(e) < 0.02 for e in errors.values()) >= 12


def test_a_pixel_on_the_subject_picks_it_over_the_person_nearer_the_rigs_centre(scene, tmp_path):
    """Two people seen whole by every camera: by default the one nearer where the cameras look is the subject;
    ``subject="CAMERA:X,Y"``, a pixel on the other in one camera at the first frame, makes the other the subject
    in every camera and frame. A camera the session lacks, or a pixel that is not X,Y, is refused by name."""
    reader = SessionReader(scene[0])
    folder = tmp_path / "pose_2d"
    other_at = np.array([0.0, 0.35, 0.0])
    for camera in reader.cameras:
        out = folder / camera.name
        out.mkdir(parents=True)
        for t in range(FRAMES):
            joints = figure_at(t)
            known = np.all(np.isfinite(joints), axis=1)
            people = [{"pose_keypoints_2d": np.column_stack([camera.project(np.where(known[:, None], joints + offset, 0.0)),
                                                             np.where(known, confidence, 0.0)]).ravel().tolist()}
                      for offset, confidence in ((other_at, 0.9), (np.zeros(3), 0.5))]
            (out / f"{camera.name}.{t:04d}.json").write_text(json.dumps({"people": people}))
    default = default_registry().create("landmarks", "openpose", folder=str(folder))
    assert all(o.confidence[t].max() == pytest.approx(0.5) for o in default.observations(reader, range(FRAMES)) for t in range(FRAMES))
    camera = reader.cameras[2]
    known = np.all(np.isfinite(figure_at(0)), axis=1)
    x, y = camera.project(figure_at(0)[known] + other_at).mean(axis=0)  # on the other person, as a user would point at it
    hinted = default_registry().create("landmarks", "openpose", folder=str(folder), subject=f"{camera.name}:{x:.1f},{y:.1f}")
    assert all(o.confidence[t].max() == pytest.approx(0.9) for o in hinted.observations(reader, range(FRAMES)) for t in range(FRAMES))
    landmarks = hinted.read(reader, range(FRAMES))
    for t in range(FRAMES):
        np.testing.assert_allclose(landmarks.positions[t], figure_at(t) + other_at, atol=1e-6)  # followed from the first frame on
    for subject, message in (("cam_9:10,10", "has no camera 'cam_9'"), (f"{camera.name}:10", "give CAMERA:X,Y")):
        with pytest.raises(InputError, match=message):
            default_registry().create("landmarks", "openpose", folder=str(folder), subject=subject).observations(reader, range(FRAMES))


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"Pose2Sim demo not found at {POSE2SIM}")
def test_the_demos_bystander_is_not_taken_for_the_subject(tmp_path):
    """At frame 37 OpenPose is, on average, more confident of a bystander at cam_01's left edge than of the
    subject, which it splits in two there: the subject is still the person the four cameras agree on, as the
    TRC places it, whole."""
    session = tmp_path / "p2s.zarr"
    assert main(["ingest", str(POSE2SIM), str(session), "--calibration", str(POSE2SIM / "Calib_qualisys.toml"), "--frames", "36:39",
                 "--scale", "0.25", "--no-progress"]) == 0
    reader = SessionReader(session)
    observed = default_registry().create("landmarks", "openpose", folder=str(POSE2SIM / "pose_2d")).observations(reader, range(3))[0]
    joints = read_trc(POSE2SIM / "joints_3d.trc")
    for t in range(3):
        seen = [observed.names.index(name) for name in joints.names if name in observed.names]
        used = observed.confidence[t, seen] > 0
        reference = reader.camera("cam_01").project(joints.positions[36 + t, [joints.names.index(observed.names[k]) for k in seen]])
        assert np.median(np.linalg.norm(observed.pixels[t, seen][used] - reference[used], axis=1)) < 10, t  # the bystander is 140 px off
    assert (observed.confidence[1] > 0).sum() >= 20  # OpenPose split the subject at frame 37: upper body (8 keypoints) and legs, joined


def _write_deeplabcut_csvs(reader: SessionReader, folder: Path, trial: str, shift: float = 0.0) -> None:
    """One DeepLabCut CSV per camera, ``TRIAL-CAMERA.csv``, of the figure's keypoints (moved ``shift`` px right);
    the Head undetected at frame 1 in every camera."""
    parts = list(FIGURE)
    for camera in reader.cameras:
        header = [["scorer", *(["DLC_resnet50"] * 3 * len(parts))], ["bodyparts", *(p for p in parts for _ in range(3))],
                  ["coords", *(["x", "y", "likelihood"] * len(parts))]]
        rows = []
        for t in range(FRAMES):
            joints = figure_at(t)[[MODELS["BODY_25B"].index(p) for p in parts]]
            pixels = camera.project(joints)
            rows.append([t, *(value for (x, y) in pixels for value in (x + shift, y, 0.95))])
        rows[1][4:7] = ["", "", ""]
        (folder / f"{trial}-{camera.name}.csv").write_text("\n".join(",".join(map(str, row)) for row in header + rows))


def test_deeplabcut_csv_keypoints_triangulate_too(scene, tmp_path):
    session, _ = scene
    reader = SessionReader(session)
    parts = list(FIGURE)
    _write_deeplabcut_csvs(reader, tmp_path, "trial")
    landmarks = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).read(reader, range(FRAMES))
    assert landmarks.names == tuple(parts)
    expected = np.stack([figure_at(t)[[MODELS["BODY_25B"].index(p) for p in parts]] for t in range(FRAMES)])
    expected[1, 1] = np.nan
    np.testing.assert_allclose(landmarks.positions, expected, atol=1e-6)
    with pytest.raises(InputError, match=r"trial-cam_0\.csv: no individual 'mouse1' \(it is a single-animal table\)"):
        default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path), individual="mouse1").read(reader, range(FRAMES))
    (tmp_path / "trial-cam_0.csv").write_text("scorer,x\nbodyparts,nose\n")
    with pytest.raises(Exception, match="not a DeepLabCut CSV"):
        default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).read(reader, range(FRAMES))


def test_a_camera_map_picks_one_trial_of_keypoint_files_side_by_side(scene, tmp_path):
    """An anipose session's pose-2d/ holds every trial's files: a camera_map naming one trial's reads that one."""
    reader = SessionReader(scene[0])
    _write_deeplabcut_csvs(reader, tmp_path, "vid01")
    _write_deeplabcut_csvs(reader, tmp_path, "vid02", shift=40.0)
    with pytest.raises(InputError, match="matches several keypoint files .*choose one with camera_map"):
        default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).observations(reader, range(FRAMES))
    camera_map = {camera.name: f"vid01-{camera.name}" for camera in reader.cameras}
    with pytest.warns(UserWarning, match=r"ignoring keypoint files of none of the cameras read \(.*\): vid02-"):
        landmarks = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path), camera_map=camera_map).read(reader, range(FRAMES))
    expected = _expected(list(FIGURE))
    expected[1, 1] = np.nan
    np.testing.assert_allclose(landmarks.positions, expected, atol=1e-6)
    # the same with one word: the trial's name, without a warning about the other trial's files
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        by_trial = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path), trial="vid01").read(reader, range(FRAMES))
    np.testing.assert_allclose(by_trial.positions, expected, atol=1e-6)
    with pytest.raises(FileNotFoundError, match=r"no keypoint file of trial 'vid03' \(no name starts with it; found: vid01-cam_0, "):
        default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path), trial="vid03").read(reader, range(FRAMES))


def _figure_pixels(camera, t: int, parts: list[str]) -> np.ndarray:
    """[L, 2] pixels of the figure's ``parts`` at frame ``t`` in ``camera``."""
    return camera.project(figure_at(t)[[MODELS["BODY_25B"].index(p) for p in parts]])


def _expected(parts: list[str]) -> np.ndarray:
    return np.stack([figure_at(t)[[MODELS["BODY_25B"].index(p) for p in parts]] for t in range(FRAMES)])


def test_deeplabcut_h5_keypoints_triangulate(scene, tmp_path):
    """DeepLabCut's HDF5 as pandas writes it (table format): the records table and the pickled column labels."""
    import pickle

    import h5py

    session, _ = scene
    reader = SessionReader(session)
    parts = list(FIGURE)
    columns = [("DLC_resnet50", part, coord) for part in parts for coord in ("x", "y", "likelihood")]
    for camera in reader.cameras:
        values = np.array([[v for x, y in _figure_pixels(camera, t, parts) for v in (x, y, 0.95)] for t in range(FRAMES)])
        values[1, 3:6] = np.nan  # the Head undetected at frame 1
        records = np.zeros(FRAMES, dtype=[("index", "<i8"), ("values_block_0", "<f8", (len(columns),))])
        records["index"], records["values_block_0"] = np.arange(FRAMES), values
        with h5py.File(tmp_path / f"trial-{camera.name}DLC_resnet50.h5", "w") as file:
            group = file.create_group("df_with_missing")
            group.create_dataset("table", data=records)
            group.attrs["non_index_axes"] = np.bytes_(pickle.dumps([(1, columns)], 0))
    landmarks = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).read(reader, range(FRAMES))
    expected = _expected(parts)
    expected[1, 1] = np.nan
    assert landmarks.names == tuple(parts)
    np.testing.assert_allclose(landmarks.positions, expected, atol=1e-6)
    # Column labels that would run code when unpickled are refused, not run.
    with h5py.File(tmp_path / "trial-cam_0DLC_resnet50.h5", "a") as file:
        file["df_with_missing"].attrs["non_index_axes"] = np.bytes_(b"cos\nsystem\n(S'true'\ntR.")
    with pytest.raises(ValueError, match=r"trial-cam_0DLC_resnet50\.h5: its column labels .* refers to os\.system"):
        default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).read(reader, range(FRAMES))


def test_sleap_analysis_h5_keypoints_triangulate(scene, tmp_path):
    """SLEAP's analysis export: datasets column-major (h5py reads tracks as [tracks, 2, nodes, frames])."""
    import h5py

    session, _ = scene
    reader = SessionReader(session)
    parts = list(FIGURE)
    for camera in reader.cameras:
        xy = np.stack([_figure_pixels(camera, t, parts) for t in range(FRAMES)])  # [frames, nodes, 2]
        other = xy + 30.0  # a second animal on track 1
        xy[2, 0] = np.nan  # the Neck absent at frame 2
        tracks = np.stack([xy, other]).transpose(0, 3, 2, 1)  # [tracks, 2, nodes, frames]
        with h5py.File(tmp_path / f"{camera.name}.analysis.h5", "w") as file:
            file["tracks"] = tracks
            file["node_names"] = np.array([part.encode() for part in parts])
            file["point_scores"] = np.full((2, len(parts), FRAMES), 0.9)
            file["track_occupancy"] = np.ones((FRAMES, 2), dtype=np.uint8)
    landmarks = default_registry().create("landmarks", "sleap", folder=str(tmp_path)).read(reader, range(FRAMES))
    expected = _expected(parts)
    expected[2, 0] = np.nan
    assert landmarks.names == tuple(parts)
    np.testing.assert_allclose(landmarks.positions, expected, atol=1e-6)
    with pytest.raises(ValueError, match=r"cam_0\.analysis\.h5: no track 2 \(the file has 2\)"):
        default_registry().create("landmarks", "sleap", folder=str(tmp_path), track=2).read(reader, range(FRAMES))


def write_slp(path: Path, names: list[str], labelled: dict[int, list[tuple[int, int, np.ndarray, np.ndarray]]], format_id: float = 1.2,
              links: list[dict] = ()) -> None:
    """A SLEAP labels file: ``labelled[frame]`` lists (instance type, track, [L, 2] points, [L] scores) per instance;
    ``links`` are its skeleton's edges as SLEAP stores them."""
    import h5py

    frames, instances, points, predicted = [], [], [], []
    for number, entries in labelled.items():
        frames.append((len(frames), 0, number, len(instances), len(instances) + len(entries)))
        for kind, track, xy, score in entries:
            table = points if kind == 0 else predicted
            instances.append((len(instances), kind, len(frames) - 1, 0, track, -1, 1.0, len(table), len(table) + len(xy), 0.0))
            for (x, y), s in zip(xy, score):
                table.append((x, y, bool(np.isfinite(x)), True) if kind == 0 else (x, y, bool(np.isfinite(x)), True, s))
    point = [("x", "<f8"), ("y", "<f8"), ("visible", "?"), ("complete", "?")]
    metadata = {"version": "2.0.0", "skeletons": [{"nodes": [{"id": k} for k in range(len(names))], "links": list(links)}], "nodes": [{"name": n, "weight": 1.0} for n in names]}
    with h5py.File(path, "w") as file:
        file.create_group("metadata").attrs["json"] = np.bytes_(json.dumps(metadata).encode())
        file["metadata"].attrs["format_id"] = format_id
        file["frames"] = np.array(frames, dtype=[("frame_id", "<u8"), ("video", "<u4"), ("frame_idx", "<u8"), ("instance_id_start", "<u8"),
                                                 ("instance_id_end", "<u8")])
        file["instances"] = np.array(instances, dtype=[("instance_id", "<i8"), ("instance_type", "u1"), ("frame_id", "<u8"), ("skeleton", "<u4"),
                                                       ("track", "<i4"), ("from_predicted", "<i8"), ("score", "<f4"), ("point_id_start", "<u8"),
                                                       ("point_id_end", "<u8"), ("tracking_score", "<f4")])
        file["points"] = np.array(points, dtype=point)
        file["pred_points"] = np.array(predicted, dtype=[*point, ("score", "<f8")])


def test_sleap_slp_keypoints_prefer_user_labels_and_triangulate(scene, tmp_path):
    session, _ = scene
    reader = SessionReader(session)
    parts = list(FIGURE)
    for camera in reader.cameras:
        labelled = {}
        for t in range(FRAMES):
            xy = _figure_pixels(camera, t, parts)
            wrong = xy + 25.0
            scores = np.full(len(parts), 0.8)
            # Frame 0: a prediction corrected by hand (the user instance wins); frame 1: predictions only, the Head
            # scored too low to use; frame 2: not labelled in this file.
            if t == 0:
                labelled[t] = [(1, -1, wrong, scores), (0, -1, xy, scores)]
            elif t == 1:
                scores[1] = 0.1
                labelled[t] = [(1, -1, xy, scores)]
        # An old file (format 1.0): pixel centres at +0.5.
        write_slp(tmp_path / f"{camera.name}.slp", parts, labelled, format_id=1.0 if camera.name == "cam_1" else 1.2)
        if camera.name == "cam_1":
            labelled = {t: [(kind, track, xy + 0.5, s) for kind, track, xy, s in entries] for t, entries in labelled.items()}
            write_slp(tmp_path / f"{camera.name}.slp", parts, labelled, format_id=1.0)
    landmarks = default_registry().create("landmarks", "sleap", folder=str(tmp_path)).read(reader, range(FRAMES))
    expected = _expected(parts)
    expected[1, 1] = np.nan
    expected[2] = np.nan
    np.testing.assert_allclose(landmarks.positions, expected, atol=1e-6)


#: Where a second animal stands, beside the subject (metres).
NEIGHBOUR = np.array([0.35, 0.35, 0.0])


def test_deeplabcut_multi_animal_files_give_the_animal_the_cameras_agree_on(scene, tmp_path):
    """A multi-animal tracker names its animals per video: the subject is ``mouse1`` in half the cameras and
    ``mouse2`` in the others, beside a more confident neighbour. The source reads the animal the cameras
    agree on, not each file's first individual; DeepLabCut's ``single`` (unique body parts) is no animal."""
    reader = SessionReader(scene[0])
    parts = list(FIGURE)
    for index, camera in enumerate(reader.cameras):
        animals = [(np.zeros(3), 0.8), (NEIGHBOUR, 0.99)][:: 1 if index % 2 == 0 else -1]
        header = [["scorer", *(["DLC_dlcrnet"] * (6 * len(parts) + 3))],
                  ["individuals", *(who for who in ("mouse1", "mouse2") for _ in range(3 * len(parts))), "single", "single", "single"],
                  ["bodyparts", *(p for _ in range(2) for p in parts for _ in range(3)), "arena", "arena", "arena"],
                  ["coords", *(["x", "y", "likelihood"] * (2 * len(parts) + 1))]]
        rows = [[t, *(value for offset, confidence in animals for x, y in _figure_pixels_at(camera, t, parts, offset) for value in (x, y, confidence)),
                 10.0, 10.0, 1.0] for t in range(FRAMES)]
        (tmp_path / f"trial-{camera.name}.csv").write_text("\n".join(",".join(map(str, row)) for row in header + rows))
    landmarks = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).read(reader, range(FRAMES))
    assert landmarks.names == tuple(parts)
    np.testing.assert_allclose(landmarks.positions, _expected(parts), atol=1e-6)
    observed = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path)).observations(reader, range(FRAMES))
    for camera, seen in zip(reader.cameras, observed, strict=True):  # mouse2 where it is the subject, not each file's first
        np.testing.assert_allclose(seen.pixels[1], _figure_pixels_at(camera, 1, parts, np.zeros(3)), atol=1e-6)
    # One individual named: the cameras where it is the neighbour give nothing, rather than another animal.
    named = default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path), individual="mouse1")
    assert [seen.confidence.max() for seen in named.observations(reader, range(FRAMES))] == pytest.approx([0.8, 0, 0.8, 0, 0.8])
    np.testing.assert_allclose(named.read(reader, range(FRAMES)).positions, _expected(parts), atol=1e-6)
    with pytest.raises(InputError, match=r"trial-cam_0\.csv: no individual 'mouse3' \(its individuals are mouse1, mouse2\)"):
        default_registry().create("landmarks", "deeplabcut", folder=str(tmp_path), individual="mouse3").read(reader, range(FRAMES))


def test_sleap_tracks_numbered_per_camera_give_the_animal_the_cameras_agree_on(scene, tmp_path):
    """Tracks are numbered in each camera's file on its own: the subject on track 0 in half the cameras and on
    track 1 in the others, beside a more confident neighbour. ``track`` reads one track alone: the cameras
    where it is the neighbour then give nothing."""
    reader = SessionReader(scene[0])
    parts = list(FIGURE)
    scores = np.full(len(parts), 0.8)
    for index, camera in enumerate(reader.cameras):
        subject, neighbour = (0, 1) if index % 2 == 0 else (1, 0)
        labelled = {t: [(1, neighbour, _figure_pixels_at(camera, t, parts, NEIGHBOUR), scores + 0.1),
                        (1, subject, _figure_pixels_at(camera, t, parts, np.zeros(3)), scores)] for t in range(FRAMES)}
        write_slp(tmp_path / f"{camera.name}.slp", parts, labelled)
    landmarks = default_registry().create("landmarks", "sleap", folder=str(tmp_path)).read(reader, range(FRAMES))
    np.testing.assert_allclose(landmarks.positions, _expected(parts), atol=1e-6)
    observed = default_registry().create("landmarks", "sleap", folder=str(tmp_path)).observations(reader, range(FRAMES))
    for camera, seen in zip(reader.cameras, observed, strict=True):
        np.testing.assert_allclose(seen.pixels[1], _figure_pixels_at(camera, 1, parts, np.zeros(3)), atol=1e-6)
    one_track = default_registry().create("landmarks", "sleap", folder=str(tmp_path), track=0).observations(reader, range(FRAMES))
    assert [seen.confidence.max() for seen in one_track] == pytest.approx([0.8, 0, 0.8, 0, 0.8])


def _figure_pixels_at(camera, t: int, parts: list[str], offset: np.ndarray) -> np.ndarray:
    """[L, 2] pixels of the figure's ``parts`` at frame ``t``, moved by ``offset`` (metres), in ``camera``."""
    return camera.project(figure_at(t)[[MODELS["BODY_25B"].index(p) for p in parts]] + offset)


#: A mouse-like skeleton that bends at a right angle (nose → spine → tail), in metres; SLEAP declares its edges.
MOUSE = {"nose": (0.0, 0.0, 0.25), "spine": (0.0, 0.0, 0.0), "tail": (0.25, 0.1, 0.0)}
MOUSE_EDGES = [("nose", "spine"), ("spine", "tail")]


def _segment(session: Path, tmp_path: Path, source: str) -> SessionReader:
    import shutil

    copy = tmp_path / "masked.zarr"
    shutil.copytree(session, copy)
    assert main(["segment", str(copy), "--segmenter", "keypoints", "--set", f"source={source}", "--no-progress"]) == 0
    return SessionReader(copy)


def _distance_to_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    share = np.clip(np.dot(point - a, b - a) / np.dot(b - a, b - a), 0, 1)
    return float(np.linalg.norm(point - (a + share * (b - a))))


def _mouse_pixels(camera) -> np.ndarray:
    return camera.project(np.array(list(MOUSE.values())))


def test_sleap_skeleton_masks_follow_the_edges_the_file_declares(scene, tmp_path):
    """Node names no human skeleton has: the mask is the file's edges drawn thick, so the inside of the bend
    (within the keypoints' hull, away from both edges) stays out."""
    import h5py

    session, _ = scene
    folder = tmp_path / "sleap"
    folder.mkdir()
    for camera in SessionReader(session).cameras:
        xy = np.repeat(_mouse_pixels(camera)[None], FRAMES, axis=0)  # [frames, nodes, 2]
        with h5py.File(folder / f"{camera.name}.analysis.h5", "w") as file:
            file["tracks"] = xy[None].transpose(0, 3, 2, 1)  # [tracks, 2, nodes, frames], as SLEAP writes it
            file["node_names"] = np.array([name.encode() for name in MOUSE])
            file["edge_names"] = np.array([(a.encode(), b.encode()) for a, b in MOUSE_EDGES])
    observed = default_registry().create("landmarks", "sleap", folder=str(folder)).observations(SessionReader(session), range(FRAMES))
    assert observed[0].edges == tuple(MOUSE_EDGES)
    reader = _segment(session, tmp_path, f'{{name="sleap", folder="{folder}"}}')
    checked = 0
    for camera in reader.cameras:
        mask, (nose, spine, tail) = reader.frame(1, camera.name).mask, _mouse_pixels(camera)
        for point in (nose, spine, tail, (nose + spine) / 2, (spine + tail) / 2):
            assert mask[int(round(point[1])), int(round(point[0]))], camera.name
        width = 0.3 * max(np.linalg.norm(nose - spine), np.linalg.norm(spine - tail), np.linalg.norm(nose - tail))
        inside = (nose + spine + tail) / 3  # inside the hull of the three keypoints
        if min(_distance_to_segment(inside, nose, spine), _distance_to_segment(inside, spine, tail)) > width / 2 + 2:
            assert not mask[int(round(inside[1])), int(round(inside[0]))], camera.name
            checked += 1
    assert checked >= 2


def test_deeplabcut_masks_without_a_skeleton_are_the_keypoints_hull(scene, tmp_path):
    """DeepLabCut declares no edges: the convex hull of the keypoints (with a disk around each), read from
    the files named one per camera."""
    import pickle

    import h5py

    session, _ = scene
    columns = [("DLC_resnet50", name, coord) for name in MOUSE for coord in ("x", "y", "likelihood")]
    files = []
    for camera in SessionReader(session).cameras:
        row = [v for x, y in _mouse_pixels(camera) for v in (x, y, 0.95)]
        records = np.zeros(FRAMES, dtype=[("index", "<i8"), ("values_block_0", "<f8", (len(columns),))])
        records["index"], records["values_block_0"] = np.arange(FRAMES), [row] * FRAMES
        files.append(tmp_path / f"{camera.name}DLC_resnet50.h5")
        with h5py.File(files[-1], "w") as file:
            group = file.create_group("df_with_missing")
            group.create_dataset("table", data=records)
            group.attrs["non_index_axes"] = np.bytes_(pickle.dumps([(1, columns)], 0))
    listed = ", ".join(f'"{path}"' for path in files)
    reader = _segment(session, tmp_path, f"{{name=\"deeplabcut\", files=[{listed}]}}")
    for camera in reader.cameras:
        mask, corners = reader.frame(2, camera.name).mask, _mouse_pixels(camera)
        for point in (*corners, corners.mean(axis=0)):
            assert mask[int(round(point[1])), int(round(point[0]))], camera.name
        assert 0.002 < mask.mean() < 0.5


def test_keypoint_sources_need_a_folder_or_files_and_name_a_stranger(tmp_path):
    with pytest.raises(ValueError, match="give either folder .* or files, not neither"):
        default_registry().create("landmarks", "sleap")
    (tmp_path / "notes.txt").write_text("")
    with pytest.raises(ValueError, match=r"notes\.txt is not a \.analysis\.h5 or \.slp file"):
        default_registry().create("landmarks", "sleap", files=[str(tmp_path / "notes.txt")]).keypoint_files()
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "cam_0.slp").write_bytes(b"")
    with pytest.raises(ValueError, match="several files are named 'cam_0'"):
        default_registry().create("landmarks", "sleap", files=[str(tmp_path / "a" / "cam_0.slp"), str(tmp_path / "b" / "cam_0.slp")]).keypoint_files()


def test_run_reads_openpose_sleap_or_deeplabcut_keypoints_from_a_folder_or_a_file(scene, tmp_path):
    from mmcsplat.pipeline.capture_session import keypoint_source

    _, openpose = scene
    assert keypoint_source(openpose) == {"name": "openpose", "folder": str(openpose)}
    for name in ("cam_0.analysis.h5", "cam_0.slp", "cam_0.csv", "cam_0DLC.h5"):
        (tmp_path / name).write_bytes(b"")
    assert keypoint_source(tmp_path / "cam_0.analysis.h5") == {"name": "sleap", "files": [str(tmp_path / "cam_0.analysis.h5")]}
    assert keypoint_source(tmp_path / "cam_0DLC.h5") == {"name": "deeplabcut", "files": [str(tmp_path / "cam_0DLC.h5")]}
    assert keypoint_source(tmp_path) == {"name": "sleap", "folder": str(tmp_path)}  # SLEAP files before DeepLabCut's
    for name in ("cam_0.analysis.h5", "cam_0.slp"):
        (tmp_path / name).unlink()
    assert keypoint_source(tmp_path) == {"name": "deeplabcut", "folder": str(tmp_path)}
    with pytest.raises(ValueError, match=r"keypoint file .*notes\.txt is neither SLEAP"):
        (tmp_path / "notes.txt").write_text("")
        keypoint_source(tmp_path / "notes.txt")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="keypoint folder .*empty holds no OpenPose camera folders"):
        keypoint_source(empty)


def test_sleap_labels_files_declare_their_body_edges_not_their_symmetries(tmp_path):
    from mmcsplat.plugins.landmarks.sleap import read_sleap_edges

    body = {"py/reduce": [{"py/type": "sleap.skeleton.EdgeType"}, {"py/tuple": [1]}]}
    symmetry = {"py/reduce": [{"py/type": "sleap.skeleton.EdgeType"}, {"py/tuple": [2]}]}
    links = [{"source": 0, "target": 1, "type": body}, {"source": 1, "target": 2, "type": {"py/id": 1}},  # py/id 1: the body type again
             {"source": 0, "target": 2, "type": symmetry}, {"source": 2, "target": 0, "type": {"py/id": 2}}]
    write_slp(tmp_path / "cam.slp", ["snout", "ear", "tail"], {0: [(0, -1, np.zeros((3, 2)), np.ones(3))]}, links=links)
    assert read_sleap_edges(tmp_path / "cam.slp") == (("snout", "ear"), ("ear", "tail"))
    write_slp(tmp_path / "bad.slp", ["snout"], {}, links=[{"source": 0, "target": 4}])
    with pytest.raises(ValueError, match=r"bad\.slp: a skeleton link does not name two of its 1 nodes"):
        read_sleap_edges(tmp_path / "bad.slp")


def test_a_head_seen_only_by_its_ears_keeps_its_disk():
    """A view from behind (no nose, no head top) still draws the head, around the ears: without it that view's mask
    cuts the head off and the fit loses it (the demo's cam_04 at frame 0 with MediaPipe's points)."""
    names = ("LShoulder", "RShoulder", "RHip", "LHip", "Nose", "LEar", "REar")
    pixels = np.array([[40.0, 50], [60, 50], [60, 90], [40, 90], [50, 30], [45, 35], [55, 35]])
    seen = np.array([True, True, True, True, False, True, True])
    torso = torso_mask(pixels, seen, names, (120, 100))
    mask = skeleton_mask(pixels, seen, names, torso, scale=40.0)
    assert mask[35, 50] and mask[25, 50]  # between the ears, and above them
    assert not skeleton_mask(pixels, seen & (np.arange(7) < 4), names, torso, scale=40.0)[25, 50]  # no head point: no disk


def test_a_null_point_is_no_detection_whatever_its_confidence(tmp_path):
    """A writer of OpenPose's format that has no point writes null for it (read as NaN): it is undetected, not a
    confident point at NaN that breaks the triangulation."""
    row = [10.0, 20.0, 0.9] * 25
    row[3:6] = [None, 21.0, 0.8]
    (tmp_path / "f.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": row}]}))
    people = read_people(tmp_path / "f.json", 25)
    assert people[0, 1].tolist() == [0.0, 0.0, 0.0] and people[0, 0].tolist() == [10.0, 20.0, 0.9]
