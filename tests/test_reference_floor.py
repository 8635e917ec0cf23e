"""The reference's floor: the nearest body of fixed bones to each frame of a 3D reference, against scipy's
least squares (the oracle), exact where the reference is one body, and the closed form of one bone."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mmcsplat.analysis.reference_floor import BONE_WEIGHT, nearest_body, reference_floor
from mmcsplat.scene.human_skeleton import fixed_bones

NAMES = ["LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "LHeel", "Neck", "LShoulder", "LElbow", "LWrist", "Head", "Nose"]
REST = np.array([[0.1, 0.9, 0.0], [-0.1, 0.9, 0.0], [0.1, 0.5, 0.02], [-0.1, 0.5, 0.0], [0.1, 0.1, 0.0], [-0.1, 0.1, 0.01],
                 [0.1, 0.05, -0.05], [0.0, 1.45, 0.0], [0.18, 1.4, 0.0], [0.2, 1.1, 0.05], [0.22, 0.85, 0.1], [0.0, 1.62, 0.0],
                 [0.0, 1.58, 0.08]])


def test_the_bones_are_those_no_pose_changes():
    bones = fixed_bones(NAMES)
    assert ("LHip", "LKnee") in bones and ("LAnkle", "LHeel") in bones and ("LHip", "RHip") in bones and ("Head", "Nose") in bones
    assert ("Neck", "LShoulder") in bones and ("RShoulder", "RElbow") not in bones  # only the names present
    assert not any({"LHip", "LShoulder"} == set(pair) or {"Neck", "Nose"} == set(pair) for pair in bones)  # the spine and the neck bend
    assert fixed_bones(["snout", "tail_base"]) == []


def _moving_body(frames: int, rng: np.random.Generator) -> np.ndarray:
    """[T, L, 3]: REST turned and moved rigidly each frame, so every distance is kept."""
    result = []
    for _ in range(frames):
        angle = rng.uniform(-np.pi, np.pi)
        turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
        result.append(REST @ turn.T + rng.normal(0, 0.5, 3))
    return np.array(result)


def test_the_nearest_body_is_scipys_least_squares():
    rng = np.random.default_rng(0)
    reference = _moving_body(12, rng) + rng.normal(0, 0.03, (12, len(NAMES), 3))  # bones 3 cm off their lengths
    pairs = fixed_bones(NAMES)
    bones = np.array([[NAMES.index(a), NAMES.index(b)] for a, b in pairs])
    lengths = np.linalg.norm(REST[bones[:, 0]] - REST[bones[:, 1]], axis=-1)
    body = nearest_body(reference, bones, lengths)
    for frame in range(len(reference)):
        def residuals(flat, target=reference[frame]):
            points = flat.reshape(-1, 3)
            return np.concatenate([(points - target).ravel(), BONE_WEIGHT * (np.linalg.norm(points[bones[:, 0]] - points[bones[:, 1]], axis=-1) - lengths)])
        expected = least_squares(residuals, reference[frame].ravel(), xtol=1e-14, ftol=1e-14, gtol=1e-14).x.reshape(-1, 3)
        np.testing.assert_allclose(body[frame], expected, atol=1e-6)
    held = np.linalg.norm(body[:, bones[:, 0]] - body[:, bones[:, 1]], axis=-1)
    np.testing.assert_allclose(held, np.broadcast_to(lengths, held.shape), atol=2e-5)  # to 20 µm: a penalty, not a constraint
    assert np.median(np.linalg.norm(body - reference, axis=-1)) > 0.005


def test_one_stretched_bone_moves_its_ends_half_way_each():
    reference = np.array([[[0.0, 0.9, 0.0], [0.0, 0.5, 0.0]], [[0.0, 0.9, 0.0], [0.0, 0.44, 0.0]]])  # the thigh 6 cm longer at frame 1
    record, body = reference_floor(["LHip", "LKnee"], reference, reference, 1)
    np.testing.assert_allclose(body[1], [[0.0, 0.87, 0.0], [0.0, 0.47, 0.0]], atol=1e-5)
    assert record["bones"] == ["LHip-LKnee"] and record["median_mm"] == pytest.approx(30.0, abs=0.01)
    assert record["carried_median_mm"] == pytest.approx(30.0, abs=0.01)  # the reference carried as it is: as far from the body


def test_a_reference_that_is_one_body_has_no_floor_and_unknown_landmarks_stay_unknown():
    rng = np.random.default_rng(1)
    reference = _moving_body(9, rng)
    reference[4, NAMES.index("LWrist")] = np.nan  # the forearm not held that frame; the rest still is
    carried = reference + np.array([0.02, 0.0, 0.0])
    record, body = reference_floor(NAMES, carried, reference, 3)
    assert record["median_mm"] == pytest.approx(0.0, abs=1e-3) and record["p90_mm"] == pytest.approx(0.0, abs=1e-3)
    assert record["carried_median_mm"] == pytest.approx(20.0, abs=1e-3)
    assert np.isnan(body[4, NAMES.index("LWrist")]).all() and np.isfinite(np.delete(body[4], NAMES.index("LWrist"), axis=0)).all()
    assert record["per_landmark_median_mm"]["LWrist"] == pytest.approx(0.0, abs=1e-3)


def test_no_floor_without_bones_or_frames_to_score():
    reference = np.zeros((5, 2, 3))
    assert reference_floor(["snout", "tail_base"], reference, reference, 2) is None
    assert reference_floor(["LHip", "LKnee"], reference[:2], reference[:2], 2) is None
