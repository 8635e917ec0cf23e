"""Movement measures on trajectories whose answers are known: constant velocity, a sinusoid, gaps, and the
left/right pairing of the naming styles in use."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmcsplat.analysis.movement import MEASURE_DESCRIPTIONS, limb_landmarks, limb_pairs, movement_summary, path_length, speed, speed_spectrum

RATE = 30.0
TIMES = np.arange(90) / RATE


def test_constant_velocity():
    positions = np.zeros((len(TIMES), 1, 3))
    positions[:, 0, 0] = 0.2 * TIMES  # 20 cm/s along x
    np.testing.assert_allclose(speed(TIMES, positions), 0.2)
    assert path_length(positions)[0] == pytest.approx(0.2 * TIMES[-1])
    summary = movement_summary(("hand",), TIMES, positions)["landmarks"]["hand"]
    assert summary["mean_speed_m_s"] == pytest.approx(0.2) and summary["range_of_motion_m"] == pytest.approx(0.9 * 0.2 * TIMES[-1], rel=0.05)


def test_a_sinusoid_has_its_frequency_range_and_peak_speed():
    frequency, amplitude = 1.5, 0.04
    positions = np.zeros((len(TIMES), 1, 3))
    positions[:, 0, 2] = amplitude * np.sin(2 * np.pi * frequency * TIMES)
    summary = movement_summary(("foot",), TIMES, positions)["landmarks"]["foot"]
    # Speed is |velocity|: it peaks twice per swing, so its spectrum's peak is at twice the swing's frequency.
    frequencies, _ = speed_spectrum(TIMES, positions[:, 0])
    assert summary["dominant_frequency_hz"] == pytest.approx(2 * frequency, abs=frequencies[1] - frequencies[0])
    assert summary["peak_speed_m_s"] == pytest.approx(2 * np.pi * frequency * amplitude, rel=0.05)
    assert summary["range_of_motion_m"] == pytest.approx(2 * amplitude * np.sin(np.pi * 0.45), rel=0.05)  # 5th–95th percentile


def test_gaps_are_skipped_and_an_unknown_landmark_has_no_measures():
    positions = np.zeros((len(TIMES), 2, 3))
    positions[:, 0, 0] = 0.1 * TIMES
    positions[40:45, 0] = np.nan
    positions[:, 1] = np.nan
    summary = movement_summary(("wrist_left", "wrist_right"), TIMES, positions)
    assert summary["landmarks"]["wrist_left"]["mean_speed_m_s"] == pytest.approx(0.1)
    assert summary["landmarks"]["wrist_right"] == dict.fromkeys(MEASURE_DESCRIPTIONS)
    assert summary["pairs"] == [{"left": "wrist_left", "right": "wrist_right", "speed_correlation": None, "path_length_ratio": None}]
    json.dumps(summary)  # JSON-ready: no NaN, no numpy types


def test_left_and_right_pair_up_and_mirrored_limbs_correlate():
    assert limb_pairs(("LWrist", "RWrist", "Neck")) == [("LWrist", "RWrist")]
    assert limb_pairs(("left_ankle", "right_ankle")) == [("left_ankle", "right_ankle")]
    assert limb_pairs(("wrist left", "wrist right", "knee left")) == [("wrist left", "wrist right")]
    assert limb_landmarks(("LWrist", "RWrist", "LHeel", "LAnkle", "RBigToe")) == {
        "left hand": "LWrist", "right hand": "RWrist", "left foot": "LAnkle", "right foot": "RBigToe"}
    assert limb_landmarks(("wrist_left", "ankle_right", "knee_left")) == {"left hand": "wrist_left", "right foot": "ankle_right"}
    rng = np.random.default_rng(0)
    swing = np.sin(2 * np.pi * 0.7 * TIMES)[:, None] * [0.05, 0, 0]
    positions = np.stack([swing, swing * [-1, 1, 1], np.cumsum(rng.normal(0, 0.003, (len(TIMES), 3)), axis=0)], axis=1)
    pairs = movement_summary(("LWrist", "RWrist", "LAnkle"), TIMES, positions)["pairs"]
    assert pairs[0]["speed_correlation"] == pytest.approx(1.0) and pairs[0]["path_length_ratio"] == pytest.approx(1.0)
    independent = movement_summary(("LWrist", "RWrist"), TIMES, positions[:, [0, 2]])["pairs"][0]
    assert abs(independent["speed_correlation"]) < 0.5
