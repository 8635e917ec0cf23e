"""Movement measures on trajectories whose answers are known analytically: constant velocity, a sinusoid,
gaps, still and jittering points, and the left/right pairing of the naming styles in use."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmcsplat.analysis.movement import (
    JOINT_ANGLES,
    LANDMARK_MEASURES,
    PAIR_MEASURES,
    angle_range,
    flexion,
    joint_angle_accuracy,
    joint_angles,
    landmark_side,
    limb_landmarks,
    limb_pairs,
    limb_symmetry,
    mean_speed,
    movement_rows,
    movement_summary,
    path_length,
    peak_speed,
    range_of_motion,
    range_of_motion_axes,
    smooth_positions,
    spectrum_summary,
    speed,
    speed_spectrum,
)

RATE = 30.0
TIMES = np.arange(90) / RATE  # 3 s at 30 fps
POSE2SIM = ("RHip", "RKnee", "RAnkle", "RBigToe", "RSmallToe", "RHeel", "LHip", "LKnee", "LAnkle", "LBigToe", "LSmallToe", "LHeel",
            "Neck", "Head", "Nose", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist")
SYNTHETIC = ("waist", "neck", *(f"{joint}_{side}" for side in ("left", "right") for joint in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")))


def _swing(frequency: float, amplitude: float, axis: int = 0, phase: float = 0.0, times: np.ndarray = TIMES) -> np.ndarray:
    """[T, 3] a point swinging along one axis."""
    track = np.zeros((len(times), 3))
    track[:, axis] = amplitude * np.sin(2 * np.pi * frequency * times + phase)
    return track


def test_constant_velocity():
    velocity = np.array([0.12, -0.16, 0.0])  # 20 cm/s
    positions = (TIMES[:, None] * velocity)[:, None]
    duration = TIMES[-1] - TIMES[0]
    np.testing.assert_allclose(speed(TIMES, positions), 0.2)  # the ends too (one-sided there)
    assert path_length(positions)[0] == pytest.approx(0.2 * duration)
    np.testing.assert_allclose(range_of_motion_axes(positions)[0], 0.9 * np.abs(velocity) * duration, atol=1e-12)  # 5th–95th percentile
    assert range_of_motion(positions)[0] == pytest.approx(0.9 * 0.16 * duration)
    summary = movement_summary(("hand",), TIMES, positions)
    hand = summary["landmarks"]["hand"]
    assert hand["mean_speed_m_s"] == pytest.approx(0.2) and hand["peak_speed_m_s"] == pytest.approx(0.2)
    assert hand["path_length_m"] == pytest.approx(0.2 * duration) and hand["range_of_motion_m"] == pytest.approx(0.9 * 0.16 * duration)
    assert hand["dominant_frequency_hz"] is None  # a constant speed has no rhythm
    assert summary["duration_s"] == pytest.approx(duration) and summary["frame_rate_hz"] == pytest.approx(RATE) and summary["frames"] == 90


def test_a_sinusoid_has_its_frequency_range_and_peak_speed():
    frequency, amplitude = 1.5, 0.04
    positions = _swing(frequency, amplitude, axis=2)[:, None]
    summary = movement_summary(("foot",), TIMES, positions)
    foot = summary["landmarks"]["foot"]
    frequencies, power = speed_spectrum(TIMES, positions[:, 0])
    step = frequencies[1] - frequencies[0]
    assert step == pytest.approx(RATE / len(TIMES)) and summary["frequency_resolution_hz"] == pytest.approx(step, abs=1e-6)
    assert frequencies[0] >= 0.1 and frequencies[-1] == pytest.approx(RATE / 2)
    # Speed is |velocity|: it peaks twice per swing, so its spectrum's peak is at twice the swing's frequency.
    assert foot["dominant_frequency_hz"] == pytest.approx(2 * frequency, abs=step)
    assert spectrum_summary(frequencies, power)[0] == pytest.approx(foot["dominant_frequency_hz"])
    assert 2 * frequency <= foot["spectral_centroid_hz"] < RATE / 2  # the harmonics of |cos| pull the centroid above the peak
    assert foot["peak_speed_m_s"] == pytest.approx(2 * np.pi * frequency * amplitude, rel=0.03)  # central differences: sinc(ωh) ≈ 0.984
    assert foot["mean_speed_m_s"] == pytest.approx(4 * frequency * amplitude, rel=0.03)  # 2πfA · mean |cos| = 2πfA · 2/π
    assert foot["path_length_m"] == pytest.approx(4 * amplitude * frequency * TIMES[-1], rel=0.03)
    # 5th–95th percentile of a continuous swing: 2A·sin(0.45π) ≈ 1.98 A; 20 samples a swing land within a few % of it.
    assert foot["range_of_motion_m"] == pytest.approx(2 * amplitude * np.sin(0.45 * np.pi), rel=0.03) and foot["range_of_motion_m"] < 2 * amplitude
    assert foot["range_of_motion_xyz_m"][:2] == [0.0, 0.0]


def test_a_short_recording_resolves_only_coarse_frequencies():
    times = np.arange(30) / RATE
    frequencies, _ = speed_spectrum(times, _swing(2.0, 0.03, times=times))
    assert frequencies[1] - frequencies[0] == pytest.approx(1.0)
    assert speed_spectrum(times[:7], _swing(2.0, 0.03, times=times[:7]))[0].size == 0  # too few frames for a spectrum
    assert spectrum_summary(np.zeros(0), np.zeros(0)) == (None, None)


def test_gaps_are_skipped_and_an_unknown_landmark_has_no_measures():
    positions = np.zeros((len(TIMES), 3, 3))
    positions[:, 0, 0] = 0.1 * TIMES
    positions[40:45, 0] = np.nan
    positions[:, 1] = np.nan
    positions[:, 2] = _swing(1.0, 0.02)
    positions[::10, 2] = np.nan
    speeds = speed(TIMES, positions)
    assert np.isnan(speeds[40:45, 0]).all() and np.isfinite(np.delete(speeds[:, 0], range(40, 45))).all()
    np.testing.assert_allclose(np.delete(speeds[:, 0], range(40, 45)), 0.1)  # one-sided beside the gap
    assert path_length(positions)[0] == pytest.approx(0.1 * (39 + 44) / RATE)  # the steps into and out of the gap are left out
    assert np.isnan(mean_speed(speeds)[1]) and np.isnan(peak_speed(speeds)[1]) and np.isnan(path_length(positions)[1])
    assert np.isnan(range_of_motion(positions)[1])
    names = ("wrist_left", "wrist_right", "knee_left")
    summary = movement_summary(names, TIMES, positions)
    assert summary["landmarks"]["wrist_left"]["mean_speed_m_s"] == pytest.approx(0.1)
    assert summary["landmarks"]["wrist_right"] == dict.fromkeys(LANDMARK_MEASURES)
    assert all(value is not None for value in summary["landmarks"]["knee_left"].values())  # a swing seen 9 frames in 10
    assert summary["landmarks"]["wrist_left"]["dominant_frequency_hz"] is None  # a steady glide has no rhythm
    assert summary["landmarks"]["knee_left"]["dominant_frequency_hz"] == pytest.approx(2.0, abs=RATE / 81)
    assert summary["pairs"] == [{"left": "wrist_left", "right": "wrist_right", "part": "wrist", "speed_correlation": None, "path_length_ratio": None}]
    json.dumps(summary, allow_nan=False)  # JSON-ready: no NaN, no numpy types


@pytest.mark.parametrize(("name", "side"), [
    ("LWrist", ("left", "wrist")), ("RBigToe", ("right", "bigtoe")), ("left_wrist", ("left", "wrist")), ("Left Wrist", ("left", "wrist")),
    ("RIGHT-ANKLE", ("right", "ankle")), ("LeftWrist", ("left", "wrist")), ("wrist_left", ("left", "wrist")), ("knee right", ("right", "knee")),
    ("big toe.R", ("right", "bigtoe")), ("l_hip", ("left", "hip")), ("wristRight", ("right", "wrist")),
    ("Neck", None), ("waist", None), ("Lower back", None), ("Nose", None), ("left", None),
])
def test_sides_of_names(name, side):
    assert landmark_side(name) == side


def test_left_and_right_pair_up_in_every_naming_style():
    assert limb_pairs(("LWrist", "RWrist", "Neck")) == [("LWrist", "RWrist")]
    assert limb_pairs(("left_ankle", "right_ankle", "left_knee")) == [("left_ankle", "right_ankle")]
    assert limb_pairs(("Left Wrist", "right wrist")) == [("Left Wrist", "right wrist")]
    assert limb_pairs(("wrist left", "wrist right", "knee left")) == [("wrist left", "wrist right")]
    assert [left for left, _ in limb_pairs(POSE2SIM)] == ["LHip", "LKnee", "LAnkle", "LBigToe", "LSmallToe", "LHeel", "LShoulder", "LElbow", "LWrist"]
    assert len(limb_pairs(SYNTHETIC)) == 6 and ("ankle_left", "ankle_right") in limb_pairs(SYNTHETIC)


def test_the_hands_and_feet():
    assert limb_landmarks(POSE2SIM) == {"left hand": "LWrist", "right hand": "RWrist", "left foot": "LAnkle", "right foot": "RAnkle"}
    assert limb_landmarks(SYNTHETIC) == {"left hand": "wrist_left", "right hand": "wrist_right", "left foot": "ankle_left", "right foot": "ankle_right"}
    assert limb_landmarks(("LWrist", "RWrist", "LBigToe", "LHeel", "RBigToe")) == {
        "left hand": "LWrist", "right hand": "RWrist", "left foot": "LHeel", "right foot": "RBigToe"}
    assert limb_landmarks(("left wrist", "ankle_right", "knee_left", "Neck")) == {"left hand": "left wrist", "right foot": "ankle_right"}
    assert limb_landmarks(("Neck", "Nose")) == {}


def test_mirrored_limbs_correlate_and_unrelated_ones_do_not():
    rng = np.random.default_rng(0)
    swing = _swing(0.7, 0.05)
    positions = np.stack([swing, swing * [-1, 1, 1],  # mirrored: the same speed
                          _swing(0.7, 0.05, phase=np.pi / 2),  # a quarter swing later: fast while the other turns
                          np.cumsum(rng.normal(0, 0.003, (len(TIMES), 3)), axis=0),  # an independent wander
                          np.cumsum(rng.normal(0, 0.003, (len(TIMES), 3)), axis=0),
                          np.zeros((len(TIMES), 3))], axis=1)  # still
    mirrored = limb_symmetry(("LWrist", "RWrist"), TIMES, positions[:, [0, 1]])[0]
    assert mirrored["speed_correlation"] == pytest.approx(1.0) and mirrored["path_length_ratio"] == pytest.approx(1.0)
    shifted = limb_symmetry(("LWrist", "RWrist"), TIMES, positions[:, [0, 2]])[0]
    assert shifted["speed_correlation"] < -0.5 and shifted["path_length_ratio"] == pytest.approx(1.0, rel=0.05)
    independent = limb_symmetry(("left ankle", "right ankle"), TIMES, positions[:, [3, 4]])[0]
    assert abs(independent["speed_correlation"]) < 0.5
    still = limb_symmetry(("wrist_left", "wrist_right"), TIMES, positions[:, [0, 5]])[0]
    assert still["speed_correlation"] is None and still["path_length_ratio"] is None  # the right did not move: no ratio
    half = positions[:, [0, 1]] * [0.5, 1, 1]
    half[:, 1] = positions[:, 1]
    assert limb_symmetry(("LWrist", "RWrist"), TIMES, half)[0]["path_length_ratio"] == pytest.approx(0.5)


def test_smoothing_removes_jitter_but_not_gaps():
    rng = np.random.default_rng(1)
    positions = np.zeros((len(TIMES), 1, 3)) + rng.normal(0, 0.002, (len(TIMES), 1, 3))  # a still point seen with 2 mm jitter
    positions[50:53] = np.nan
    np.testing.assert_array_equal(smooth_positions(positions), positions)  # off by default
    smoothed = smooth_positions(positions, 7)
    assert np.isnan(smoothed[50:53]).all() and np.isfinite(np.delete(smoothed, range(50, 53), axis=0)).all()
    raw, light = np.nanmean(speed(TIMES, positions)), np.nanmean(speed(TIMES, positions, smoothing_window=7))
    assert light < 0.5 * raw
    moving = _swing(1.0, 0.03)[:, None]  # a real swing keeps its speed
    assert peak_speed(speed(TIMES, moving, smoothing_window=7))[0] == pytest.approx(peak_speed(speed(TIMES, moving))[0], rel=0.02)
    summary = movement_summary(("p",), TIMES, positions, smoothing_window=7)
    assert summary["smoothing_window"] == 7 and summary["landmarks"]["p"]["path_length_m"] < path_length(positions)[0]


def test_every_summary_key_has_a_plain_sentence():
    summary = movement_summary(POSE2SIM, TIMES, np.repeat(_swing(1.0, 0.02)[:, None], len(POSE2SIM), axis=1))
    keys = {key for values in summary["landmarks"].values() for key in values}
    keys |= {key for pair in summary["pairs"] for key in pair} - {"left", "right", "part"}
    assert keys == set(LANDMARK_MEASURES) | set(PAIR_MEASURES)
    tables = {**LANDMARK_MEASURES, **PAIR_MEASURES, **JOINT_ANGLES}
    assert summary["measures"] == {key: {"unit": m.unit, "label": m.label, "sentence": m.sentence} for key, m in tables.items()}
    assert all(measure.sentence.endswith(".") and measure.label for measure in tables.values())
    assert len(summary["pairs"]) == 9 and all(pair["speed_correlation"] == pytest.approx(1.0) for pair in summary["pairs"])
    json.dumps(summary, allow_nan=False)


def _plane(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two orthonormal directions of a random plane in space."""
    u, v = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 2)))[0].T
    return u, v


def _bent(angle_deg: np.ndarray, u: np.ndarray, v: np.ndarray, start: np.ndarray, lengths=(0.10, 0.09)) -> np.ndarray:
    """[T, 3, 3] a three-point chain (proximal, joint, distal) whose second segment turns by ``angle_deg`` from
    the first's direction ``u`` towards ``v``."""
    angle = np.radians(np.atleast_1d(angle_deg))[:, None]
    joint = start + lengths[0] * u
    distal = joint + lengths[1] * (np.cos(angle) * u + np.sin(angle) * v)
    return np.stack([np.broadcast_to(start, distal.shape), np.broadcast_to(joint, distal.shape), distal], axis=1)


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 135.0, 179.0])
def test_a_chain_bent_by_a_known_angle(angle):
    u, v = _plane(int(angle))
    chain = _bent(np.array([angle]), u, v, np.array([0.3, -0.2, 0.1]))
    np.testing.assert_allclose(flexion(chain[:, 0], chain[:, 1], chain[:, 2]), angle, atol=1e-6)


def test_knee_and_elbow_flexion_through_a_known_range_in_every_naming_style():
    knee = 20 + 50 * (1 - np.cos(2 * np.pi * 0.5 * TIMES)) / 2  # 20° to 70° and back, every 2 s
    elbow = 10 + 80 * TIMES / TIMES[-1]  # 10° straightening to 90° bent
    u, v = _plane(1)
    leg, arm = _bent(knee, u, v, np.array([0.0, 0.1, 0.0])), _bent(elbow, -u, v, np.array([0.2, 0.1, 0.0]))
    for names in (("RHip", "RKnee", "RAnkle", "RShoulder", "RElbow", "RWrist"),  # Pose2Sim / OpenPose
                  ("hip_right", "knee_right", "ankle_right", "shoulder_right", "elbow_right", "wrist_right"),  # the synthetic infant
                  ("right hip", "right knee", "right ankle", "right shoulder", "right elbow", "right wrist")):  # a DeepLabCut project
        angles, left_out = joint_angles(names, np.concatenate([leg, arm], axis=1))
        np.testing.assert_allclose(angles["right_knee_flexion"], knee, atol=1e-6)
        np.testing.assert_allclose(angles["right_elbow_flexion"], elbow, atol=1e-6)
        assert left_out["left_knee_flexion"] == "no left hip among the landmarks"  # one side only: the other is left out, not guessed
        assert set(left_out) == {f"left_{key}" for key in JOINT_ANGLES} | {"right_hip_flexion", "right_shoulder_flexion"}  # no trunk
    extremes = angle_range(angles["right_knee_flexion"])
    assert extremes["min_deg"] == pytest.approx(20, abs=1e-6) and extremes["max_deg"] == pytest.approx(70, abs=1e-6)
    assert extremes["range_deg"] == pytest.approx(50, abs=1e-6) and extremes["frames"] == len(TIMES)


def test_hip_and_shoulder_flexion_against_the_trunk():
    hip, shoulder = 40 + 30 * np.sin(2 * np.pi * TIMES), 75.0 * TIMES / TIMES[-1]
    down, forward = np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])  # an infant lying on its back along x, facing up
    def limb(angle: np.ndarray, root: np.ndarray) -> np.ndarray:
        turned = np.radians(angle)[:, None]
        return root + 0.1 * (np.cos(turned) * down + np.sin(turned) * forward)

    points = {"neck": np.array([0.10, 0.0, 0.0]), "waist": np.array([-0.07, 0.0, 0.0]),
              "hip_left": np.array([-0.10, -0.045, 0.0]), "hip_right": np.array([-0.10, 0.045, 0.0]),
              "shoulder_left": np.array([0.07, -0.07, 0.0]), "shoulder_right": np.array([0.07, 0.07, 0.0])}
    tracks = {name: np.broadcast_to(point, (len(TIMES), 3)) for name, point in points.items()}
    tracks |= {f"knee_{side}": limb(hip, points[f"hip_{side}"]) for side in ("left", "right")}
    tracks |= {f"elbow_{side}": limb(shoulder, points[f"shoulder_{side}"]) for side in ("left", "right")}
    angles, left_out = joint_angles(tuple(tracks), np.stack(list(tracks.values()), axis=1))
    for side in ("left", "right"):
        np.testing.assert_allclose(angles[f"{side}_hip_flexion"], hip, atol=1e-6)
        np.testing.assert_allclose(angles[f"{side}_shoulder_flexion"], shoulder, atol=1e-6)
    assert "left_hip_flexion" not in left_out and "no left ankle" in left_out["left_knee_flexion"]
    # Pose2Sim's names: no mid-hip landmark, so the trunk runs from the neck to between the two hips.
    pose2sim = {"neck": "Neck", "hip_left": "LHip", "hip_right": "RHip", "knee_left": "LKnee", "knee_right": "RKnee"}
    angles, _ = joint_angles(tuple(pose2sim.values()), np.stack([tracks[name] for name in pose2sim], axis=1))
    np.testing.assert_allclose(angles["right_hip_flexion"], hip, atol=1e-6)
    angles, left_out = joint_angles(("LHip", "RHip", "LKnee"), np.stack([tracks["hip_left"], tracks["hip_right"], tracks["knee_left"]], axis=1))
    assert angles == {} and left_out["left_hip_flexion"] == "no neck or thorax landmark nor both shoulders"


def test_joint_angles_in_the_summary_and_its_rows():
    u, v = _plane(2)
    leg = _bent(np.full(len(TIMES), 30.0), u, v, np.zeros(3))
    leg[10:20, 2] = np.nan  # the ankle unseen for 10 frames: the knee angle is unknown there, not filled in
    summary = movement_summary(("LHip", "LKnee", "LAnkle"), TIMES, leg)
    knee = summary["joint_angles"]["left_knee_flexion"]
    assert knee["frames"] == len(TIMES) - 10 and knee["per_frame_deg"][10:20] == [None] * 10
    assert knee["min_deg"] == pytest.approx(30, abs=1e-6) and knee["range_deg"] == pytest.approx(0, abs=1e-6)
    assert set(summary["joint_angles"]) == {"left_knee_flexion"} and "right_knee_flexion" in summary["joint_angles_left_out"]
    rows = movement_rows(summary)
    assert ("left_knee_flexion", "range_deg", knee["range_deg"], "deg") in rows
    assert ("LAnkle", "mean_speed_m_s", summary["landmarks"]["LAnkle"]["mean_speed_m_s"], "m/s") in rows
    assert ("LHip", "range_of_motion_xyz_m:z", summary["landmarks"]["LHip"]["range_of_motion_xyz_m"][2], "m") in rows
    json.dumps(summary, allow_nan=False)


def test_joint_angle_accuracy_against_the_source():
    u, v = _plane(3)
    names = ("left_hip", "left_knee", "left_ankle", "left_shoulder", "left_elbow")
    truth = _bent(np.full(10, 30.0), u, v, np.zeros(3))
    carried = _bent(np.array([30.0] + [34.0] * 5 + [40.0] * 4), u, v, np.zeros(3))  # frame 0, the fitted one, is not scored
    arm = np.full((10, 2, 3), np.nan)  # no wrist and an unknown arm: nothing to score there
    accuracy = joint_angle_accuracy(names, np.concatenate([carried, arm], axis=1), np.concatenate([truth, arm], axis=1))
    assert accuracy["pairs"] == 9 and accuracy["median_deg"] == pytest.approx(4, abs=1e-6)
    assert accuracy["p90_deg"] == pytest.approx(10, abs=1e-6) and accuracy["per_angle_median_deg"] == {"left_knee_flexion": pytest.approx(4, abs=1e-6)}
    assert joint_angle_accuracy(names[3:], arm, arm) is None
