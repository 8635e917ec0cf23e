"""The iterative dynamics: rigidity priors, constant-velocity prediction, and tracking a small moving scene
end to end (`mmcsplat track`, then `mmcsplat evaluate`), with the drift detector quiet on a sound run and
firing on a broken one."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from fitting_scene import moved, subject, write_fitted_run, write_ground_truth, write_session

from mmcsplat.analysis.drift import detect_drift
from mmcsplat.cli import main
from mmcsplat.pipeline.track import TRACK_INFO, track_run
from mmcsplat.plugins.dynamics.iterative import IterativeDynamics
from mmcsplat.plugins.dynamics.rigidity import NeighbourGraph, RigidityPrior
from mmcsplat.scene.quaternions import quat_multiply, quat_to_rotmat
from mmcsplat.storage.curves import read_curves
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader
from mmcsplat.training.model import GaussianModel, LearningRates

FRAMES = 3
# 60 Gaussians of 2 cm seen at 96 × 72 px: sparse enough that each one can be followed.
TRUTH = subject(count=60, scale=0.02)
# Few iterations per frame keep the test fast; a faster means learning rate lets them keep up with the
# subject's 5–17 mm per frame.
FAST = ["dynamics.iterations=40", "dynamics.means_lr=1e-3"]
BROKEN = ["dynamics.iterations=40", "dynamics.lambda_rigid=0", "dynamics.means_lr=0.2", "dynamics.lambda_seg=3"]


def random_rotation(generator: torch.Generator) -> torch.Tensor:
    q = torch.randn(4, generator=generator, dtype=torch.float64)
    return q / q.norm()


# ------------------------------------------------------------------------------------------ priors


def test_rigid_motion_costs_nothing_and_bending_does():
    g = torch.Generator().manual_seed(0)
    means = torch.randn(60, 3, generator=g, dtype=torch.float64) * 0.05
    quats = torch.randn(60, 4, generator=g, dtype=torch.float64)
    foreground = torch.ones(60, dtype=torch.bool)
    foreground[:5] = False
    graph = NeighbourGraph.build(means, foreground, k=8, lambda_w=2000.0)
    assert graph.neighbours.shape == (55, 8) and not torch.isin(graph.foreground, torch.arange(5)).any()
    torch.testing.assert_close(graph.weights, torch.exp(-2000.0 * graph.distances**2))
    prior = RigidityPrior(graph)
    prior.remember(means, quats)

    rotation = random_rotation(g)
    R = quat_to_rotmat(rotation[None])[0]
    moved_means = means @ R.T + torch.tensor([0.1, -0.2, 0.05], dtype=torch.float64)
    moved_quats = quat_multiply(rotation.expand(60, 4), quats / quats.norm(dim=-1, keepdim=True))
    assert max(float(loss) for loss in prior.losses(moved_means, moved_quats)) < 1e-6

    stretched = moved_means * torch.tensor([1.3, 1.0, 1.0], dtype=torch.float64)
    rigid, rot, iso = prior.losses(stretched, moved_quats)
    assert rigid > 1e-4 and iso > 1e-4 and rot < 1e-6
    twisted = moved_quats.clone()
    twisted[::2] = quat_multiply(random_rotation(g).expand(30, 4), twisted[::2])
    assert prior.losses(moved_means, twisted)[1] > 1e-3


def test_a_first_frame_reference_keeps_a_slide_costly():
    """A rigid motion costs nothing against the first frame; a slide of half the cloud keeps its cost after
    remember() with the first frame as reference, where the previous-frame reference forgives it."""
    g = torch.Generator().manual_seed(1)
    means = torch.randn(40, 3, generator=g, dtype=torch.float64) * 0.02
    quats = random_rotation(g).expand(40, 4).clone()
    graph = NeighbourGraph.build(means, torch.ones(40, dtype=torch.bool), k=6, lambda_w=2000.0)
    first, previous = RigidityPrior(graph, reference="first"), RigidityPrior(graph)
    for prior in (first, previous):
        prior.remember(means, quats)

    rotation = random_rotation(g)
    moved = means @ quat_to_rotmat(rotation[None])[0].T + torch.tensor([0.03, 0.0, -0.01], dtype=torch.float64)
    turned = quat_multiply(rotation.expand(40, 4), quats)
    assert max(float(loss) for loss in first.losses(moved, turned)) < 1e-6

    slid = moved.clone()
    slid[means[:, 0] > 0] += torch.tensor([0.005, 0.0, 0.0], dtype=torch.float64)  # half the cloud slides 5 mm
    for prior in (first, previous):
        prior.remember(slid, turned)
    assert previous.losses(slid, turned)[0] < 1e-6  # forgiven: the slide became the reference
    assert first.losses(slid, turned)[0] > 1e-4  # still measured against the first frame


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("reference", ["previous", "first"])
def test_the_numba_priors_match_their_torch_reference(dtype, reference):
    """Each loss and its gradients in means and rotations, through the numba passes and through torch: each
    loss weighted differently, so a gradient given to the wrong loss shows."""
    g = torch.Generator().manual_seed(3)
    means = (torch.randn(80, 3, generator=g, dtype=torch.float64) * 0.05).to(dtype)
    quats = torch.randn(80, 4, generator=g, dtype=torch.float64).to(dtype)
    foreground = torch.rand(80, generator=g) > 0.2
    prior = RigidityPrior(NeighbourGraph.build(means, foreground, k=7, lambda_w=500.0), reference)
    prior.remember(means, quats)
    means = (means + 0.004 * torch.randn(80, 3, generator=g, dtype=torch.float64).to(dtype)).requires_grad_(True)
    quats = (quats + 0.05 * torch.randn(80, 4, generator=g, dtype=torch.float64).to(dtype)).requires_grad_(True)
    weights = torch.tensor([1.0, 3.0, 7.0], dtype=dtype)
    results = []
    for losses in (prior.losses, prior.reference_losses):
        means.grad = quats.grad = None
        values = torch.stack(losses(means, quats))
        (weights * values).sum().backward()
        results.append((values.detach(), means.grad.clone(), quats.grad.clone()))
    tolerance = {"rtol": 1e-9, "atol": 1e-12} if dtype == torch.float64 else {"rtol": 2e-4, "atol": 1e-6}
    assert results[0][0].dtype == dtype and (results[0][0] > 1e-4).all()
    for fast, oracle in zip(results[0], results[1], strict=True):
        torch.testing.assert_close(fast, oracle, **tolerance)


def test_a_strided_graph_reaches_further_at_the_same_size():
    means = torch.randn(200, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 0.05
    foreground = torch.ones(200, dtype=torch.bool)
    near = NeighbourGraph.build(means, foreground, k=5, lambda_w=2000.0)
    far = NeighbourGraph.build(means, foreground, k=5, lambda_w=2000.0, stride=3)
    wide = NeighbourGraph.build(means, foreground, k=15, lambda_w=2000.0)
    assert far.neighbours.shape == near.neighbours.shape == (200, 5)
    torch.testing.assert_close(far.neighbours, wide.neighbours[:, ::3])  # every third of the 15 nearest
    assert far.distances.median() > near.distances.median()


def test_too_few_foreground_gaussians_is_an_error():
    with pytest.raises(ValueError, match="at least two foreground Gaussians"):
        NeighbourGraph.build(torch.zeros(3, 3), torch.tensor([True, False, False]), k=20, lambda_w=2000.0)


def test_constant_velocity_prediction():
    truth = subject(count=10)
    gaussians = type(truth)(*(getattr(truth, f).float() for f in ("means", "quats", "log_scales", "opacity_logits", "colors", "features")))
    model = GaussianModel(gaussians, ("a",), LearningRates(), 1.0)
    before = model.params["means"].detach().clone()
    step = torch.tensor([0.01, -0.02, 0.0])
    with torch.no_grad():
        model.params["means"] += step
    unit = model.params["quats"].detach() / model.params["quats"].detach().norm(dim=-1, keepdim=True)
    # The previous state given with flipped quaternion signs: the same rotations, so no rotational velocity.
    current = IterativeDynamics()._predict(model, (before, -unit))
    torch.testing.assert_close(current[0], before + step)
    torch.testing.assert_close(model.params["means"].detach(), before + 2 * step)
    torch.testing.assert_close(model.params["quats"].detach(), unit)


# ---------------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("moving")
    session = write_session(root / "scene.zarr", frames=FRAMES, absent=(("cam_3", 1),), zoom=2, truth=TRUTH)
    return root, session, write_ground_truth(root / "truth.zarr", FRAMES, TRUTH)


@pytest.fixture(scope="module")
def tracked(scene):
    root, session, truth = scene
    run = write_fitted_run(root / "run", session, TRUTH)
    assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", *sum((["--set", o] for o in FAST), [])]) == 0
    return run


def test_track_writes_every_frame(tracked):
    reader = TrackReader(tracked)
    assert (reader.num_frames, reader.num_gaussians, reader.method) == (FRAMES, 60, "iterative")
    first = TRUTH
    np.testing.assert_allclose(reader.means(0), first.means.float().numpy(), atol=1e-6)  # frame 0 = the fit
    assert reader.static == ("log_scales", "opacity_logits")  # frozen after the first frame
    torch.testing.assert_close(reader.params(2)["opacity_logits"], first.opacity_logits.float())
    info = json.loads((tracked / TRACK_INFO).read_text())
    assert info["method"] == "iterative" and info["params"] == {"iterations": 40, "means_lr": 1e-3}
    cameras = [frame["cameras"] for frame in info["summary"]["frames"]]
    assert cameras == [3, 4]  # cam_3 is absent at frame 1: skipped there
    # RUN/curves.csv: the fit's rows kept, then one tracking row per tracked frame with its summary's means.
    curve = read_curves(tracked)
    tracking = [row for row in curve if row["stage"] == "track"]
    assert [row["stage"] for row in curve] == sorted(row["stage"] for row in curve)  # fit, then track
    assert [(row["step"], row["frame"]) for row in tracking] == [(40, 1), (80, 2)]
    for row, frame in zip(tracking, info["summary"]["frames"], strict=True):
        assert row["loss"] == pytest.approx(frame["loss"], rel=1e-5) and row["psnr"] == pytest.approx(frame["psnr"], rel=1e-5)


def test_tracking_follows_the_subject(tracked, scene):
    reader = TrackReader(tracked)
    for t in range(1, FRAMES):
        truth = moved(TRUTH, t).means.numpy()
        tracked_error = np.linalg.norm(reader.means(t) - truth, axis=1)
        standing_error = np.linalg.norm(TRUTH.means.numpy() - truth, axis=1)
        assert np.median(tracked_error) < 0.6 * np.median(standing_error), t


def test_evaluate_adds_tracking_metrics(tracked, scene, capsys):
    root, session, truth = scene
    assert main(["evaluate", str(tracked), "--ground-truth", str(truth), "--json"]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert len(metrics["per_frame_val_masked_psnr"]) == FRAMES
    assert metrics["tracking_followed_points"] == 60
    # The subject moves 5–17 mm per frame; tracked, the error stays well under it.
    assert 0 < metrics["tracking_median_mm"] < 5 and metrics["tracking_p90_mm"] >= metrics["tracking_median_mm"]
    assert metrics["tracking_2d_median_px"] is not None
    assert metrics["drift"] is False


def test_drift_detector_fires_on_a_broken_run_only(tracked, scene):
    root, session, truth = scene
    reader = SessionReader(session)
    cameras = list(reader.train_cameras)
    sound = detect_drift(TrackReader(tracked), reader, cameras)
    assert not sound.drift and sound.counts == [0] * FRAMES

    broken = write_fitted_run(root / "broken", session, TRUTH)
    track_run(broken, dynamics="iterative", overrides=BROKEN, progress=False)
    report = detect_drift(TrackReader(broken), reader, cameras)
    assert report.drift and report.counts[0] == 0 and max(report.counts) > 0.1 * report.foreground
    assert report.drifted


def test_track_refuses_to_overwrite_and_defaults_to_iterative(tracked, scene, tmp_path, capsys):
    assert main(["track", str(tracked), "--dynamics", "iterative", "--no-progress"]) == 2
    assert "already exists" in capsys.readouterr().err
    # A bad value is named before the existing tracks: fixing it is the first thing to do.
    assert main(["track", str(tracked), "--set", "dynamics.iterations=abc", "--no-progress"]) == 2
    assert "parameter 'iterations' must be an integer or one of 'auto', got 'abc'" in capsys.readouterr().err
    assert main(["track", str(tracked), "--set", "dynamics.iterations=-1", "--no-progress"]) == 2
    assert "iterations: steps a frame must be a whole number ≥ 0 or 'auto', got -1" in capsys.readouterr().err
    assert main(["track", str(tracked), "--frames", "1:3", "--no-progress"]) == 2
    assert "tracking runs on from the fitted frame 0" in capsys.readouterr().err
    _, session, _ = scene
    run = write_fitted_run(tmp_path / "run", session, TRUTH)  # its configuration names no dynamics method
    assert main(["track", str(run), "--set", "dynamics.iterations=1", "--frames", ":2", "--no-progress"]) == 0
    assert "with iterative (the default: the configuration names no dynamics method)" in capsys.readouterr().out
    record = json.loads((run / TRACK_INFO).read_text())
    assert record["method"] == "iterative" and record["method_default"] is True and record["params"] == {"iterations": 1}


def test_auto_steps_follow_the_session_frame_rate(scene, tmp_path, capsys):
    """The method's default: 3000 steps a second of video, so the 30 fps session's frames take 100 each."""
    _, session, _ = scene
    run = write_fitted_run(tmp_path / "run", session, TRUTH)
    assert main(["track", str(run), "--frames", ":2", "--no-progress"]) == 0
    assert "with iterative (the default: the configuration names no dynamics method) at 100 steps a frame in" in capsys.readouterr().out
    summary = json.loads((run / TRACK_INFO).read_text())["summary"]
    assert summary["iterations_per_frame"] == 100 and [frame["iterations"] for frame in summary["frames"]] == [100]
