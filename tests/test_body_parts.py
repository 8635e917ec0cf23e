"""The length prior within body parts: which Gaussians belong to which part, pairs drawn within a part
only, a joint that bends freely and a limb that cannot shorten."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from fitting_scene import subject, write_fitted_run, write_session

from mmcsplat.cli import main
from mmcsplat.pipeline.track import TRACK_INFO
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.dynamics.body_parts import HUMAN_PARTS, PartPairs, part_members
from mmcsplat.storage.tracks import TrackReader

#: A torso 0.5 m long and a left arm hanging along x from the shoulder, bent nowhere yet.
JOINTS = {"LShoulder": np.array([0.0, 0.2, 0.5]), "RShoulder": np.array([0.0, -0.2, 0.5]), "LHip": np.array([0.0, 0.1, 0.0]),
          "RHip": np.array([0.0, -0.1, 0.0]), "LElbow": np.array([0.3, 0.2, 0.5]), "LWrist": np.array([0.6, 0.2, 0.5])}
TORSO = 0.5


def arm_points() -> np.ndarray:
    """Points along the left arm (x from 0.05 to 0.6 m), 2 cm off its axis, and one at the elbow."""
    along = np.linspace(0.05, 0.6, 12)
    return np.concatenate([np.column_stack([along, np.full(12, 0.22), np.full(12, 0.5)]), [[0.3, 0.2, 0.5]]])


def test_a_gaussian_belongs_to_its_nearest_part_and_at_a_joint_to_both():
    points = np.array([[0.15, 0.22, 0.5], [0.45, 0.22, 0.5], [0.3, 0.2, 0.5], [0.3, 0.2, 1.5]])
    members, parts = part_members(points, JOINTS, HUMAN_PARTS, reach=0.1, margin=0.01)
    upper, forearm = parts.index(("LShoulder", "LElbow")), parts.index(("LElbow", "LWrist"))
    assert members[0, upper] and not members[0, forearm]
    assert members[1, forearm] and not members[1, upper]
    assert members[2, upper] and members[2, forearm]
    assert not members[3].any()  # a metre from every part
    assert ("RShoulder", "RElbow") not in parts  # the skeleton has no right elbow: a part needs two joints


def test_the_neck_is_a_part_between_the_torso_and_the_head():
    # Upright: the neck's base between the shoulders, the crown 0.27 m above it, the nose in front of the face.
    joints = {**JOINTS, "Neck": np.array([0.0, 0.0, 0.5]), "Head": np.array([0.0, 0.0, 0.77]), "Nose": np.array([0.1, 0.0, 0.65])}
    members, parts = part_members(np.array([[-0.03, 0.0, 0.6]]), joints, HUMAN_PARTS, reach=0.15 * TORSO, margin=0.02 * TORSO)
    assert parts[members[0].argmax()] == ("Neck", "Head") and members[0].sum() == 1


def pairs_on_the_arm() -> tuple[PartPairs, torch.Tensor, np.ndarray]:
    means = torch.as_tensor(arm_points(), dtype=torch.float32)
    pairs = PartPairs.build(means, np.arange(len(means)), JOINTS, HUMAN_PARTS, partners=4, reach=0.1, margin=0.02)
    return pairs, means, arm_points()


def test_pairs_join_members_of_one_part_only_and_never_a_gaussian_to_itself():
    pairs, means, points = pairs_on_the_arm()
    members, parts = part_members(points, JOINTS, HUMAN_PARTS, reach=0.1 * TORSO, margin=0.02 * TORSO)
    assert len(pairs.first) and not (pairs.first == pairs.second).any()
    shared = members[pairs.first.numpy()] & members[pairs.second.numpy()]
    assert shared.any(axis=1).all()
    assert torch.allclose(pairs.lengths, (means[pairs.first] - means[pairs.second]).norm(dim=-1))
    assert pairs.loss(means).item() == pytest.approx(0.0, abs=1e-6)


def test_the_numba_loss_matches_its_torch_reference():
    pairs, means, _ = pairs_on_the_arm()
    moved = (means + 0.01 * torch.randn(means.shape, generator=torch.Generator().manual_seed(0))).requires_grad_(True)
    fast = pairs.loss(moved)
    fast.backward()
    grad, moved.grad = moved.grad.clone(), None
    oracle = pairs.reference_loss(moved)
    oracle.backward()
    assert fast.item() > 1e-3
    torch.testing.assert_close(fast, oracle, rtol=2e-5, atol=1e-7)
    torch.testing.assert_close(grad, moved.grad, rtol=2e-4, atol=1e-7)


def test_no_pairs_cost_nothing():
    empty = torch.zeros(0, dtype=torch.int64)
    pairs = PartPairs(empty, empty, torch.zeros(0), (), ())
    means = torch.rand(5, 3, requires_grad=True)
    loss = pairs.loss(means)
    loss.backward()
    assert loss.item() == 0.0 and not means.grad.any()


def test_bending_at_the_elbow_is_free_and_shortening_the_forearm_is_not():
    pairs, means, points = pairs_on_the_arm()
    elbow = JOINTS["LElbow"]
    angle = np.pi / 3
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    bent = points.copy()
    beyond = points[:, 0] > elbow[0]
    bent[beyond] = (points[beyond] - elbow) @ turn.T + elbow
    shortened = points.copy()
    shortened[beyond, 0] = elbow[0] + 0.6 * (points[beyond, 0] - elbow[0])
    loss_bent = pairs.loss(torch.as_tensor(bent, dtype=torch.float32)).item()
    loss_short = pairs.loss(torch.as_tensor(shortened, dtype=torch.float32)).item()
    # only the Gaussians on the joint's surface, in both parts, strain as it bends
    assert loss_bent < 0.1 * loss_short, (loss_bent, loss_short)
    stretched = torch.as_tensor(shortened, dtype=torch.float32).requires_grad_(True)
    pairs.loss(stretched).backward()
    wrist_end = int(np.argmax(points[:, 0]))
    assert stretched.grad[wrist_end, 0] < 0  # descent moves the shortened forearm's end out again


def test_a_skeleton_without_shoulders_and_hips_is_an_error_naming_its_joints():
    joints = {name: JOINTS[name] for name in ("LElbow", "LWrist")}
    with pytest.raises(InputError, match="LElbow"):
        PartPairs.build(torch.zeros(4, 3), np.arange(4), joints, HUMAN_PARTS, partners=2, reach=0.3, margin=0.05)


# ------------------------------------------------------------------------------ tracking with the prior

SCENE = subject(count=60, scale=0.02)
FRAMES = 3
#: A torso over the scene's x < 0 half and a forearm over its bending x > 0 half (see fitting_scene.moved); the scene is a
#: 24 × 12 × 8 cm cloud, not limbs, so the parts reach 0.3 of this 12 cm torso to hold most of it.
SKELETON = {"LShoulder": (0, 0.03, 0), "RShoulder": (0, -0.03, 0), "LHip": (-0.12, 0.03, 0), "RHip": (-0.12, -0.03, 0), "LElbow": (0, 0, 0),
            "LWrist": (0.12, 0, 0)}
SETTINGS = ["dynamics.iterations=30", "dynamics.means_lr=1e-3", "dynamics.predict=constant-velocity"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("body-parts")
    (root / "skeleton.csv").write_text("name,x,y,z\n" + "".join(f"{name},{x},{y},{z}\n" for name, (x, y, z) in SKELETON.items()))
    return root, write_session(root / "scene.zarr", frames=FRAMES, truth=SCENE)


def test_tracking_with_the_parts_holds_their_lengths(scene):
    root, session = scene
    changes, summaries = {}, {}
    for name, extra in (("free", []), ("held", ["dynamics.lambda_parts=10", "dynamics.part_reach=0.3", "dynamics.skeleton.name=csv",
                                                   f"dynamics.skeleton.path={root / 'skeleton.csv'}"])):
        run = write_fitted_run(root / name, session, SCENE)
        assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", *sum((["--set", s] for s in (*SETTINGS, *extra)), [])]) == 0
        summaries[name] = json.loads((run / TRACK_INFO).read_text())["summary"]["body_parts"]
        reader = TrackReader(run)
        first, last = reader.means(0), reader.means(FRAMES - 1)
        pairs = PartPairs.build(torch.as_tensor(first), np.arange(len(first)), {n: np.array(p, float) for n, p in SKELETON.items()}, HUMAN_PARTS,
                                partners=8, reach=0.3, margin=0.02, seed=1)
        changes[name] = pairs.loss(torch.as_tensor(last)).item()
    assert summaries["free"] is None
    # The neck, which the skeleton lacks, between its shoulders.
    assert summaries["held"]["parts"] == ["LShoulder–LElbow", "LElbow–LWrist", "LShoulder–RShoulder–RHip–LHip–Neck"] and min(summaries["held"]["gaussians"]) > 0
    assert changes["held"] < 0.5 * changes["free"], changes


def test_the_prior_without_a_skeleton_is_an_error(scene, capsys):
    root, session = scene
    run = write_fitted_run(root / "no-skeleton", session, SCENE)
    assert main(["track", str(run), "--no-progress", "--set", "dynamics.lambda_parts=1"]) != 0
    assert "dynamics.skeleton.name=trc" in capsys.readouterr().err
