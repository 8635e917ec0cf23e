"""Landmarks carried by Gaussians: a rigid motion carries them exactly (rotation included), anchors that
tear apart show in the spread, a landmark far from every Gaussian is left out, a reference off at the fitted
frame is outvoted by the frames after it, and the accuracy figures are the ones asked for."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mmcsplat.analysis.landmark_binding import confidence, landmark_accuracy
from mmcsplat.scene.landmark_anchors import bind_landmarks, bind_over_frames, carry

NAMES = ("wrist", "elbow", "far")


def cloud(seed: int = 0, count: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """(means [N, 3] in a 10 cm ball, random unit quaternions (w, x, y, z) [N, 4])."""
    rng = np.random.default_rng(seed)
    means = rng.normal(scale=0.05, size=(count, 3))
    quats = Rotation.random(count, random_state=seed).as_quat(scalar_first=True)
    return means, quats


def moved(means: np.ndarray, quats: np.ndarray, rotation: Rotation, shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cloud after a rigid motion: centres rotated and shifted, each Gaussian's orientation turned too."""
    turned = (rotation * Rotation.from_quat(quats, scalar_first=True)).as_quat(scalar_first=True)
    return rotation.apply(means) + shift, turned


def test_a_rigid_motion_carries_landmarks_exactly():
    means, quats = cloud()
    landmarks = np.array([[0.02, 0.0, 0.01], [-0.03, 0.02, 0.0], [1.0, 1.0, 1.0]])
    binding = bind_landmarks(NAMES, landmarks, means, quats, np.arange(len(means)))
    assert binding.unbound == ["far"] and binding.bound.tolist() == [True, True, False]
    np.testing.assert_allclose(binding.weights[binding.bound].sum(axis=1), 1.0)
    # At the fitted frame the carried landmarks are where they were bound.
    start, spread = carry(binding, means, quats)
    np.testing.assert_allclose(start[:2], landmarks[:2], atol=1e-12)
    assert np.isnan(start[2]).all() and np.isnan(spread[2])
    rotation, shift = Rotation.from_euler("xyz", [0.4, -0.2, 0.9]), np.array([0.1, -0.05, 0.3])
    positions, spread = carry(binding, *moved(means, quats, rotation, shift))
    np.testing.assert_allclose(positions[:2], rotation.apply(landmarks[:2]) + shift, atol=1e-10)
    np.testing.assert_allclose(spread[:2], 0.0, atol=1e-10)  # rigid: every anchor proposes the same point
    assert confidence(spread[:2]) == pytest.approx([1.0, 1.0])


def test_rotation_carries_an_off_centre_landmark_where_a_translation_alone_would_not():
    means, quats = cloud(1)
    landmark = np.array([[0.0, 0.0, 0.09]])  # off the cloud's side: anchors 4–9 cm away
    binding = bind_landmarks(("knee",), landmark, means, quats, np.arange(len(means)), anchors=4)
    rotation = Rotation.from_euler("z", 0.6)
    positions, _ = carry(binding, *moved(means, quats, rotation, np.zeros(3)))
    np.testing.assert_allclose(positions, rotation.apply(landmark), atol=1e-10)
    unturned, _ = carry(binding, rotation.apply(means), quats)  # centres moved, orientations not
    assert np.linalg.norm(unturned - rotation.apply(landmark)) > 0.005


def test_anchors_torn_apart_show_in_the_spread_and_only_candidates_carry():
    means, quats = cloud(2)
    landmark = np.array([[0.0, 0.0, 0.0]])
    half = np.arange(len(means)) % 2 == 0
    binding = bind_landmarks(("hip",), landmark, means, quats, np.flatnonzero(half))
    assert set(binding.anchors[0]) <= set(np.flatnonzero(half))
    torn = means.copy()
    torn[binding.anchors[0][:4]] += [0.05, 0.0, 0.0]  # half the anchors jump 5 cm
    _, spread = carry(binding, torn, quats)
    assert 0.015 < spread[0] < 0.05 and confidence(spread)[0] < 0.3


def test_accuracy_over_moving_frames_beside_landmarks_held_still():
    frames, names = 5, ("a", "b")
    reference = np.zeros((frames, 2, 3))
    reference[:, 0, 0] = np.arange(frames) * 0.02  # a moves 2 cm a frame; b stays
    carried = reference + [0.001, 0.0, 0.0]  # carried 1 mm off everywhere
    carried[0] = reference[0]
    accuracy = landmark_accuracy(names, carried, reference)
    assert accuracy.median_mm == pytest.approx(1.0) and accuracy.pairs == 8
    assert accuracy.moving_pairs == 4 and accuracy.moving_median_mm == pytest.approx(1.0)
    assert accuracy.still_moving_median_mm == pytest.approx(50.0)  # a held at frame 0: 2, 4, 6, 8 cm off
    assert accuracy.per_frame_median_mm[0] is None and accuracy.per_landmark_median_mm["b"] == pytest.approx(1.0)


def test_binding_over_frames_outvotes_a_reference_off_at_the_fitted_frame():
    means, quats = cloud(3)
    true = np.array([[0.02, 0.01, 0.0], [-0.02, 0.0, 0.01], [0.0, 0.03, -0.01]])
    states, reference = [], []
    for t in range(5):
        rotation, shift = Rotation.from_euler("y", 0.2 * t), np.array([0.03 * t, 0.0, 0.0])
        states.append(moved(means, quats, rotation, shift))
        reference.append(rotation.apply(true) + shift)
    reference = np.stack(reference)
    reference[0, 0] += [0.05, 0.0, 0.0]  # the first landmark 5 cm off at the fitted frame
    reference[2, 0] -= [0.0, 0.04, 0.0]  # ... and 4 cm off two frames later
    reference[0, 2] = np.nan  # the third unknown at the fitted frame
    names = ("ankle", "knee", "toe")
    binding = bind_over_frames(names, reference, states, np.arange(len(means)))
    assert binding.bound.all()
    np.testing.assert_allclose(carry(binding, *states[0])[0], true, atol=1e-9)
    one = bind_over_frames(names, reference[:1], states[:1], np.arange(len(means)))  # the fitted frame alone
    assert one.unbound == ["toe"]
    np.testing.assert_allclose(carry(one, *states[4])[0][0] - reference[4, 0], Rotation.from_euler("y", 0.8).apply([0.05, 0, 0]), atol=1e-9)


def test_accuracy_leaves_out_the_frames_the_landmarks_were_bound_from():
    reference = np.zeros((5, 1, 3))
    reference[:, 0, 0] = np.arange(5) * 0.02
    carried = reference + [0.002, 0.0, 0.0]
    carried[:3] = reference[:3]
    accuracy = landmark_accuracy(("a",), carried, reference, bound_from=3)
    assert accuracy.pairs == 2 and accuracy.median_mm == pytest.approx(2.0)
    assert accuracy.per_frame_median_mm[:3] == [None] * 3 and accuracy.still_median_mm == pytest.approx(70.0)
