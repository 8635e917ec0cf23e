"""The first-frame trainer: it learns, resumes exactly, stops cleanly on NaN, and rejects bad input."""

from __future__ import annotations

import json

import pytest
import torch
from fitting_scene import every_renderer, write_config, write_session

from mmcsplat.cli import main
from mmcsplat.configuration.config import load_config
from mmcsplat.pipeline.evaluate import evaluate
from mmcsplat.pipeline.fit import CHECKPOINT, FirstFrameFit
from mmcsplat.pipeline.track import track_run
from mmcsplat.storage.curves import read_curves
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.finite import NonFiniteError
from mmcsplat.training.loop import TrainingLoop


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return SessionReader(write_session(tmp_path_factory.mktemp("scene") / "scene.zarr"))


def test_fit_learns_and_evaluates(session, tmp_path):
    config = write_config(tmp_path / "fit.toml", iterations=60)
    assert main(["fit", session.url, "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["status"] == "complete" and info["iterations"] == 60
    assert info["heldout_cameras"] == ["cam_0"] and len(info["train_cameras"]) == 4
    metrics = evaluate(tmp_path / "run")
    assert (tmp_path / "run" / "metrics.json").exists()
    # 80 iterations from random points: well above an empty render's masked PSNR (~8 dB here).
    assert metrics["train_masked_psnr"] > 14
    assert metrics["val_masked_psnr"] is not None and metrics["num_gaussians"] > 0
    # The same scores inside the mask less its 1-pixel edge (visual_hull.eroded), per camera and averaged.
    interior = [scores["interior_masked_psnr"] for scores in metrics["per_camera"].values() if scores["split"] == "train"]
    assert metrics["train_interior_masked_psnr"] == pytest.approx(sum(interior) / len(interior)) and metrics["val_interior_masked_psnr"] > 10


def test_killed_run_resumes_to_the_same_parameters(session, tmp_path, monkeypatch):
    config = load_config(write_config(tmp_path / "fit.toml", iterations=30, checkpoint_every=10))
    FirstFrameFit(session, config, tmp_path / "straight", progress=False).run()

    original = TrainingLoop._prune

    def killed_at_15(self, step):
        original(self, step)
        if step == 14:
            raise KeyboardInterrupt  # as a kill between checkpoints
    monkeypatch.setattr(TrainingLoop, "_prune", killed_at_15)
    with pytest.raises(KeyboardInterrupt):
        FirstFrameFit(session, config, tmp_path / "resumed", progress=False).run()
    # Checkpointed at 10 iterations: in the middle of the third block of the 4 training cameras.
    assert torch.load(tmp_path / "resumed" / CHECKPOINT, weights_only=False)["step"] == 10
    monkeypatch.setattr(TrainingLoop, "_prune", original)
    FirstFrameFit(session, config, tmp_path / "resumed", progress=False).run()

    straight = torch.load(tmp_path / "straight" / CHECKPOINT, weights_only=False)["model"]["params"]
    resumed = torch.load(tmp_path / "resumed" / CHECKPOINT, weights_only=False)["model"]["params"]
    for name, tensor in straight.items():
        torch.testing.assert_close(resumed[name], tensor, rtol=0, atol=0, msg=name)
    # The loss record (block means over 7 complete blocks of 4 iterations) is the same too.
    straight_info, resumed_info = (json.loads((tmp_path / run / "run.json").read_text()) for run in ("straight", "resumed"))
    assert straight_info["loss_min"] is not None and straight_info["loss_min"] <= straight_info["loss_final"]
    assert (resumed_info["loss_min"], resumed_info["loss_final"]) == (straight_info["loss_min"], straight_info["loss_final"])
    # The resumed run says so; the straight one never resumed.
    assert (resumed_info["resumed_from"], straight_info["resumed_from"]) == (10, None) and resumed_info["version"] == 2
    # RUN/curves.csv: one row per block, the same for both; no row of the killed stretch is repeated.
    straight_curve, resumed_curve = (read_curves(tmp_path / run) for run in ("straight", "resumed"))
    assert [row["step"] for row in straight_curve] == [4, 8, 12, 16, 20, 24, 28]
    assert [(r["loss"], r["psnr"], r["gaussians"]) for r in resumed_curve] == [(r["loss"], r["psnr"], r["gaussians"]) for r in straight_curve]
    assert min(row["loss"] for row in straight_curve) == pytest.approx(straight_info["loss_min"], rel=1e-5)
    assert all(row["stage"] == "fit" and row["frame"] == 0 and 0 < row["psnr"] < 100 for row in straight_curve)


def test_nan_stops_cleanly_keeping_the_last_good_checkpoint(session, tmp_path, monkeypatch):
    config = load_config(write_config(tmp_path / "fit.toml", iterations=40, checkpoint_every=10))
    original = TrainingLoop._prune

    def inject_nan(self, step):
        original(self, step)
        if step == 15:
            with torch.no_grad():
                self.model.params["log_scales"][3, 0] = float("nan")
    monkeypatch.setattr(TrainingLoop, "_prune", inject_nan)
    with pytest.raises(NonFiniteError, match=r"parameter of 'log_scales'.*1 Gaussian.*iteration 15"):
        FirstFrameFit(session, config, tmp_path / "run", progress=False).run()
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["status"] == "diverged" and "log_scales" in info["error"]
    checkpoint = torch.load(tmp_path / "run" / CHECKPOINT, weights_only=False)
    assert checkpoint["step"] == 10
    assert all(torch.isfinite(t).all() for t in checkpoint["model"]["params"].values())


def test_nan_through_the_cli_is_a_clear_error(session, tmp_path, capsys):
    config = write_config(tmp_path / "fit.toml", iterations=5)
    fit = ["fit", session.url, "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress"]
    assert main([*fit, "--set", "fit.lrs.opacity_logits=inf"]) == 2  # refused before training
    assert "lrs: opacity_logits must be a finite number > 0, got inf" in capsys.readouterr().err
    assert main([*fit, "--set", "fit.lrs.log_scales=1e30"]) == 2  # finite, but training blows up
    assert "non-finite" in capsys.readouterr().err


def test_empty_masks_everywhere_is_an_error(tmp_path):
    names = tuple(f"cam_{i}" for i in range(5))
    session = SessionReader(write_session(tmp_path / "blank.zarr", blank=names))
    with pytest.raises(ValueError, match="mask is empty in every training view"):
        FirstFrameFit(session, load_config(write_config(tmp_path / "fit.toml")), tmp_path / "run", progress=False)


def test_camera_that_never_sees_the_subject_is_flagged(tmp_path):
    session = SessionReader(write_session(tmp_path / "one-blind.zarr", blank=("cam_2",)))
    config = load_config(write_config(tmp_path / "fit.toml", iterations=3))
    with pytest.warns(UserWarning, match="cam_2"):
        fit = FirstFrameFit(session, config, tmp_path / "run", progress=False)
    info = fit.run()
    assert any("cam_2" in warning for warning in info.warnings)
    # Three of its four training cameras see the subject: under-constrained.
    assert info.warnings[0].startswith("only 3 training cameras see the subject at frame 0")


def test_unknown_holdout_and_missing_masks(session, tmp_path):
    config = load_config(write_config(tmp_path / "fit.toml"))
    with pytest.raises(ValueError, match="cam_9"):
        FirstFrameFit(session, config, tmp_path / "run", holdout=["cam_9"], progress=False)


@pytest.mark.parametrize("backend", every_renderer())
def test_a_built_in_configuration_runs_unchanged_on_every_backend(session, tmp_path, backend):
    """paper-masked as shipped — only its size shrunk to the tiny scene — fits on each renderer by name."""
    config = load_config("paper-masked", ["fit.iterations=40", "initializer.random.num_points=600", "initializer.random.half_size=0.3"])
    info = FirstFrameFit(session, config, tmp_path / backend, backend=backend, progress=False).run()
    assert info.status == "complete" and info.renderer == backend
    metrics = evaluate(tmp_path / backend, backend=backend)
    assert metrics["train_masked_psnr"] > 12, metrics  # an empty render scores about 8 dB inside these masks


def test_cameras_of_different_sizes_fit_track_and_evaluate_together(tmp_path):
    session = write_session(tmp_path / "mixed.zarr", frames=2, taller=("cam_1", "cam_0"))
    assert {(c.width, c.height) for c in SessionReader(session).cameras} == {(48, 36), (48, 38)}
    config = load_config(write_config(tmp_path / "fit.toml", iterations=8, checkpoint_every=8))
    assert FirstFrameFit(SessionReader(session), config, tmp_path / "run", progress=False).run().complete
    track_run(tmp_path / "run", dynamics="iterative", overrides=["dynamics.iterations=2"], progress=False)
    metrics = evaluate(tmp_path / "run")
    assert {"cam_0", "cam_1", "cam_2"} <= set(metrics["per_camera"]) and metrics["val_masked_psnr"] is not None


def test_every_fit_logs_to_its_run_and_verbose_shows_it(session, tmp_path, capsys):
    config = write_config(tmp_path / "fit.toml", iterations=4, checkpoint_every=2)
    out, extra = tmp_path / "run", tmp_path / "extra.log"
    assert main(["fit", session.url, "--config", str(config), "--out", str(out), "--no-progress", "--verbose", "--log-file", str(extra)]) == 0
    log = (out / "log.txt").read_text()
    assert "fit of session" in log and "fit complete: 4 iterations" in log
    assert "fit of session" in capsys.readouterr().err and "fit complete" in extra.read_text()
    assert main(["fit", session.url, "--config", str(config), "--out", str(out), "--no-progress"]) == 0  # nothing left to do
    assert (out / "log.txt").read_text().count("fit of session") == 2  # appended, not replaced
    assert "fit of session" not in capsys.readouterr().err  # quiet without --verbose
