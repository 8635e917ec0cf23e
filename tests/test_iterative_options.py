"""The iterative dynamics' options: the flow loss, coarse to fine and the per-frame stopping rule, each
tracking a small moving scene end to end (`mmcsplat track`), and the schedule of the settling rates."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from fitting_scene import moved, subject, write_fitted_run, write_flow_session, write_session

from mmcsplat.cli import main
from mmcsplat.pipeline.track import TRACK_INFO
from mmcsplat.plugins.dynamics.iterative import IterativeDynamics
from mmcsplat.storage.tracks import TrackReader

TRUTH = subject(count=60, scale=0.02)
FRAMES = 3
FAST = ["dynamics.iterations=40", "dynamics.means_lr=1e-3"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("iterative-options")
    return root, write_flow_session(root / "scene.zarr", FRAMES, TRUTH)


def tracked(root, session, name, *settings) -> tuple[dict, float]:
    """The summary of a track with ``settings`` and its median error at the last frame (metres)."""
    run = write_fitted_run(root / name, session, TRUTH)
    assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", *sum((["--set", s] for s in (*FAST, *settings)), [])]) == 0
    error = np.linalg.norm(TrackReader(run).means(FRAMES - 1) - moved(TRUTH, FRAMES - 1).means.numpy(), axis=1)
    return json.loads((run / TRACK_INFO).read_text())["summary"], float(np.median(error))


def test_each_frame_runs_its_iterations_without_a_stopping_rule(scene):
    summary, _ = tracked(*scene, "plain")
    assert [frame["iterations"] for frame in summary["frames"]] == [40, 40] and summary["flow_loss"] is False


def test_the_stopping_rule_ends_a_converged_frame_early(scene):
    summary, _ = tracked(*scene, "stopped", "dynamics.stop_window=5", "dynamics.stop_tolerance=0.5")
    iterations = [frame["iterations"] for frame in summary["frames"]]
    # a block must improve on the lowest by half to count: the second block already fails
    assert iterations == [10, 10], iterations


def test_flow_loss_and_coarse_to_fine_track_the_subject(scene):
    root, session = scene
    summary, error = tracked(root, session, "flow-loss", "dynamics.lambda_flow=0.1", "dynamics.coarse_iterations=10")
    assert summary["flow_loss"] is True and [frame["iterations"] for frame in summary["frames"]] == [40, 40]
    standing = float(np.median(np.linalg.norm(TRUTH.means.numpy() - moved(TRUTH, FRAMES - 1).means.numpy(), axis=1)))
    assert error < 0.3 * standing, (error, standing)


def test_coarse_iterations_must_leave_full_size_ones(scene, capsys):
    root, session = scene
    run = write_fitted_run(root / "all-coarse", session, TRUTH)
    assert main(["track", str(run), "--no-progress", "--set", "dynamics.iterations=10", "--set", "dynamics.coarse_iterations=10"]) != 0
    assert "dynamics.coarse_iterations" in capsys.readouterr().err


def test_flow_loss_without_flow_is_an_error_naming_the_session(tmp_path, capsys):
    session = write_session(tmp_path / "scene.zarr", frames=2, truth=TRUTH)
    run = write_fitted_run(tmp_path / "run", session, TRUTH)
    assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", "--set", "dynamics.lambda_flow=1"]) != 0
    message = capsys.readouterr().err
    assert "mmcsplat flow" in message and "scene.zarr" in message


def test_the_means_and_rotations_rates_settle_over_each_frame():
    optimizers = {name: torch.optim.Adam([torch.zeros(1, requires_grad=True)], lr=lr) for name, lr in
                  (("means", 1e-2), ("quats", 1e-3), ("color_logits", 5e-3))}
    settle = IterativeDynamics(iterations=11, lr_final_ratio=0.01)._settling(SimpleNamespace(optimizers=optimizers))
    rates = []
    for step in (0, 5, 10, 0):  # the next frame starts again from the full rates
        settle(step)
        rates.append([optimizers[name].param_groups[0]["lr"] for name in ("means", "quats", "color_logits")])
    assert np.allclose(rates, [[1e-2, 1e-3, 5e-3], [1e-3, 1e-4, 5e-3], [1e-4, 1e-5, 5e-3], [1e-2, 1e-3, 5e-3]])



def test_a_final_rate_of_zero_is_refused():  # every step after a frame's first would then change nothing
    with pytest.raises(ValueError, match="lr_final_ratio"):
        IterativeDynamics(lr_final_ratio=0)
