"""Keypoint guidance: the loss vanishes where the carried keypoints project onto their detections, its
gradient pulls them towards a moved detection, a held-out camera's and unconfident detections never enter,
and on a small moving scene guided tracking carries the keypoints closer than unguided (`mmcsplat track`)."""

from __future__ import annotations

import json
from pathlib import Path

import attrs
import numpy as np
import pytest
import torch
from fitting_scene import moved, ring_camera, single_precision, subject, write_fitted_run, write_session

from mmcsplat.cli import main
from mmcsplat.pipeline.track import TRACK_INFO
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugins.landmarks.openpose import MODELS
from mmcsplat.scene.landmark_anchors import bind_landmarks, carry
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader
from mmcsplat.training.keypoint_guidance import KeypointGuidance

TRUTH = subject(count=60, scale=0.02)
NAMES = ("a", "b", "c")
CAMERAS = tuple(ring_camera(f"cam_{i}", 2 * np.pi * i / 4, zoom=10) for i in range(4))  # 400 px focal length: 1 px ≈ 3 mm
TRAINING = CAMERAS[1:]  # cam_0 held out


def params() -> dict[str, torch.Tensor]:
    gaussians = single_precision(TRUTH)
    return {"means": gaussians.means.clone().requires_grad_(True), "quats": gaussians.quats.clone().requires_grad_(True),
            "opacity_logits": gaussians.opacity_logits}


def detections(points: np.ndarray, cameras=CAMERAS, confidence: float = 0.9) -> list[KeypointObservations]:
    """Each camera's exact projections of ``points`` [T, L, 3] at confidence 0.9."""
    frames = np.arange(len(points))
    return [KeypointObservations(c.name, NAMES, frames, c.project(points.reshape(-1, 3)).reshape(*points.shape[:2], 2),
                                 np.full(points.shape[:2], confidence)) for c in cameras]


def landmarks() -> np.ndarray:
    """[2, 3, 3]: three Gaussian centres at frame 0, and the same at frame 1."""
    points = TRUTH.means.numpy()[[3, 17, 40]]
    return np.stack([points, points])


def guidance(observations, cameras=TRAINING) -> KeypointGuidance:
    return KeypointGuidance.bind(observations, cameras, [0, 1], params(), np.arange(TRUTH.count), weight=1.0, huber_px=2.0)


def shifted(observations: list[KeypointObservations], camera: str, frame: int, keypoint: int, by: tuple[float, float],
            confidence: float | None = None) -> list[KeypointObservations]:
    """``observations`` with one detection moved ``by`` pixels (and its confidence set)."""
    result = []
    for o in observations:
        if o.camera == camera:
            pixels, weights = o.pixels.copy(), o.confidence.copy()
            pixels[frame, keypoint] += by
            if confidence is not None:
                weights[frame, keypoint] = confidence
            o = attrs.evolve(o, pixels=pixels, confidence=weights)
        result.append(o)
    return result


def test_the_loss_vanishes_where_the_keypoints_project_onto_their_detections():
    guide = guidance(detections(landmarks()))
    assert guide.binding.bound.all()
    model = params()
    guide.observe(1)
    for camera in TRAINING:
        assert guide.loss(camera.name, model["means"], model["quats"]).item() == pytest.approx(0.0, abs=1e-6)


def test_its_gradient_pulls_the_anchors_towards_a_moved_detection():
    observed = shifted(detections(landmarks()), "cam_1", 1, 0, (6.0, -3.0))
    guide, model = guidance(observed), params()
    guide.observe(1)
    target = observed[1].pixels[1, 0]

    def distance() -> float:
        with torch.no_grad():
            point = guide.positions(model["means"], model["quats"])[0].double().numpy()
        return float(np.linalg.norm(CAMERAS[1].project(point[None])[0] - target))

    before = distance()
    assert before > 5
    loss = guide.loss("cam_1", model["means"], model["quats"])
    assert loss.item() > 0
    loss.backward()
    pull = model["means"].grad.norm(dim=1).numpy()
    others = np.setdiff1d(np.arange(len(pull)), guide.binding.anchors[0])
    assert pull[others].max() < 0.01 * pull.max()  # keypoint a's anchors are pulled (the others match within float32)
    with torch.no_grad():
        model["means"] -= 0.005 * model["means"].grad / model["means"].grad.norm(dim=1).max()  # 5 mm at most
    assert distance() < before - 1


def test_a_heldout_cameras_detections_never_enter():
    points = landmarks()
    honest = guidance(detections(points))
    lying = guidance(shifted(shifted(detections(points), "cam_0", 0, 1, (30.0, 0.0)), "cam_0", 1, 2, (0.0, 40.0)))
    np.testing.assert_array_equal(lying.binding.anchors, honest.binding.anchors)
    np.testing.assert_allclose(lying.binding.offsets, honest.binding.offsets)
    lying.observe(1)
    model = params()
    assert lying.loss("cam_0", model["means"], model["quats"]) is None
    assert lying.summary()["cameras"] == ["cam_1", "cam_2", "cam_3"]


def test_unconfident_detections_are_ignored():
    points = landmarks()
    exact = guidance(detections(points))
    # a wild detection whose source found it below its min_confidence (stored as confidence 0) pulls nothing
    unconfident = guidance(shifted(detections(points), "cam_2", 1, 1, (50.0, 50.0), confidence=0.0))
    # a detection off by a few pixels, within what the other cameras allow, pulls
    confident = guidance(shifted(detections(points), "cam_2", 1, 1, (6.0, 6.0)))
    model = params()
    for guide in (exact, unconfident, confident):
        guide.observe(1)
    assert unconfident.loss("cam_2", model["means"], model["quats"]).item() == pytest.approx(
        exact.loss("cam_2", model["means"], model["quats"]).item(), abs=1e-6)
    assert confident.loss("cam_2", model["means"], model["quats"]).item() > 1.0
    assert confident.summary()["inconsistent_detections"] == {"cam_1": 0, "cam_2": 0, "cam_3": 0}


def test_a_detection_the_other_cameras_contradict_is_left_out():
    points = landmarks()
    exact = guidance(detections(points))
    wild = guidance(shifted(detections(points), "cam_2", 1, 1, (50.0, 50.0)))  # 71 px; the tolerance is 12 px here
    model = params()
    for guide in (exact, wild):
        guide.observe(1)
    assert wild.loss("cam_2", model["means"], model["quats"]).item() == pytest.approx(
        exact.loss("cam_2", model["means"], model["quats"]).item(), abs=1e-6)
    assert wild.summary()["inconsistent_detections"]["cam_2"] == 1
    # seen by two cameras only, a keypoint whose detections no point explains pulls in neither
    two = [o for o in detections(points) if o.camera != "cam_3"]
    split = guidance(shifted(two, "cam_1", 1, 0, (0.0, 40.0)), cameras=TRAINING[:2])  # across the epipolar line
    split.observe(1)
    assert split.summary()["inconsistent_detections"] == {"cam_1": 1, "cam_2": 1}
    assert split.loss("cam_1", model["means"], model["quats"]).item() == pytest.approx(0.0, abs=1e-6)


def test_too_few_training_cameras_is_an_error_naming_them():
    with pytest.raises(InputError, match="two training cameras"):
        guidance(detections(landmarks(), cameras=CAMERAS[:2]), cameras=TRAINING)


# ---------------------------------------------------------------------------------------- end to end

FRAMES = 2
KEYPOINTS = np.flatnonzero(TRUTH.means.numpy()[:, 0] > 0.0)[:25]  # Gaussians of the bending half carry the keypoints


def write_keypoints(folder: Path, session: SessionReader) -> None:
    """OpenPose files per camera: the keypoint Gaussians' true centres projected (confidence 0.9)."""
    for camera in session.cameras:
        (folder / camera.name).mkdir(parents=True)
        for t in range(FRAMES):
            pixels = camera.project(moved(TRUTH, t).means.numpy()[KEYPOINTS])
            person = np.column_stack([pixels, np.full(len(pixels), 0.9)])
            (folder / camera.name / f"{camera.name}_{t:012d}_keypoints.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": person.ravel().tolist()}]}))


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("keypoint-guidance")
    session = write_session(root / "scene.zarr", cameras=4, frames=FRAMES, truth=TRUTH)
    write_keypoints(root / "pose_2d", SessionReader(session))
    return root, session


def keypoint_error(run: Path) -> float:
    """Median distance (m) at the last frame between the keypoints carried by the tracks and their truth."""
    reader = TrackReader(run)
    first = TRUTH.means.numpy()[KEYPOINTS]
    binding = bind_landmarks(MODELS["BODY_25B"][: len(KEYPOINTS)], first, TRUTH.means.numpy(), TRUTH.quats.numpy(), np.arange(TRUTH.count))
    last = reader.params(FRAMES - 1)
    carried, _ = carry(binding, last["means"].double().numpy(), last["quats"].double().numpy())
    return float(np.median(np.linalg.norm(carried - moved(TRUTH, FRAMES - 1).means.numpy()[KEYPOINTS], axis=1)))


def test_guided_tracking_carries_the_keypoints_closer(capture):
    root, session = capture
    settings = ["dynamics.iterations=8", "dynamics.means_lr=1e-3", "dynamics.predict=constant-velocity"]
    guide = ["dynamics.lambda_keypoints=0.05", "dynamics.keypoints.name=openpose", f"dynamics.keypoints.folder={root / 'pose_2d'}"]
    errors, summaries = {}, {}
    for name, extra in (("unguided", []), ("guided", guide)):
        run = write_fitted_run(root / name, session, TRUTH)
        assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", *sum((["--set", s] for s in (*settings, *extra)), [])]) == 0
        errors[name] = keypoint_error(run)
        summaries[name] = json.loads((run / TRACK_INFO).read_text())["summary"]
    assert summaries["unguided"]["keypoint_guidance"] is None
    record = summaries["guided"]["keypoint_guidance"]
    assert record["cameras"] == ["cam_1", "cam_2", "cam_3"] and record["weight"] == 0.05 and len(record["keypoints"]) == len(KEYPOINTS)
    assert errors["guided"] < 0.7 * errors["unguided"], errors


def test_guidance_without_a_keypoint_source_is_an_error(capture, capsys):
    root, session = capture
    run = write_fitted_run(root / "no-source", session, TRUTH)
    assert main(["track", str(run), "--no-progress", "--set", "dynamics.lambda_keypoints=1"]) != 0
    assert "dynamics.keypoints.name=openpose" in capsys.readouterr().err
