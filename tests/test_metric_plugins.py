"""Metric plugins are chosen by name, as every other kind is: a run's configuration's ``[[metric]]`` tables
(with parameters) and ``mmcsplat evaluate --metric NAME`` add scores beside the built-in PSNR and SSIM; a
metric that fails is named."""

from __future__ import annotations

import json
import types

import numpy as np
import pytest
from fitting_scene import write_fitted_run, write_session

from mmcsplat import Registration, hookimpl
from mmcsplat.configuration.registry import Registry, UnknownPluginError
from mmcsplat.pipeline.evaluate import evaluate
from mmcsplat.plugin_api.interfaces import Metric
from mmcsplat.training.plugin_hooks import PluginRuntimeError


class ScaledAbsoluteError(Metric):
    """The mean absolute difference times ``scale`` (a parameter, so the configuration's table is seen)."""

    higher_is_better = False

    def __init__(self, scale: float = 1.0) -> None:
        self.scale = scale

    def __call__(self, prediction, target, mask=None):
        difference = np.abs(prediction - target).mean(axis=-1)
        return float(self.scale * (difference[mask].mean() if mask is not None else difference.mean()))


class Failing(Metric):
    def __call__(self, prediction, target, mask=None):
        raise ZeroDivisionError("no pixels")


@pytest.fixture
def registry():
    plugin = types.ModuleType("metric_plugin")
    plugin.mmcsplat_metrics = hookimpl(lambda: [Registration("mae", f"{__name__}:ScaledAbsoluteError"),
                                                Registration("failing", f"{__name__}:Failing")])
    return Registry([("metric-plugin", "test-dist", plugin)])


def test_a_configurations_metric_tables_and_named_metrics_score_every_camera(tmp_path, registry):
    session = write_session(tmp_path / "s.zarr")
    run = write_fitted_run(tmp_path / "run", session)
    metrics = evaluate(run, registry, metrics=["mae"])
    assert metrics["metrics"] == ["mae"] and {"val_mae", "val_masked_mae", "train_mae", "train_masked_mae"} <= set(metrics)
    camera = metrics["per_camera"]["cam_0"]
    assert camera["split"] == "val" and camera["mae"] >= 0 and "masked_mae" in camera
    record = json.loads((run / "run.json").read_text())
    record["config_values"]["metric"] = [{"name": "mae", "scale": 10.0}, {"name": "psnr"}]  # psnr: built in, computed once
    (run / "run.json").write_text(json.dumps(record))
    scaled = evaluate(run, registry, metrics=["mae"])
    assert scaled["metrics"] == ["mae"] and scaled["val_mae"] == pytest.approx(10 * metrics["val_mae"])
    assert json.loads((run / "metrics.json").read_text())["per_camera"]["cam_1"]["mae"] == pytest.approx(10 * camera_value(metrics, "cam_1"))
    with pytest.raises(UnknownPluginError, match="unknown metric 'nope'"):
        evaluate(run, registry, metrics=["nope"])
    with pytest.raises(PluginRuntimeError, match=r"metric plugin 'failing' failed in __call__\(\): ZeroDivisionError: no pixels"):
        evaluate(run, registry, metrics=["failing"])


def camera_value(metrics: dict, camera: str) -> float:
    return metrics["per_camera"][camera]["mae"]


def test_evaluate_names_a_metric_plugin_on_the_command_line(tmp_path, capsys):
    from mmcsplat.cli import main

    session = write_session(tmp_path / "s.zarr")
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["evaluate", str(run), "--metric", "ssim", "--metric", "psnr", "--no-progress"]) == 0  # the built-in ones: no new rows
    assert "val_masked_psnr" in capsys.readouterr().out
    assert main(["evaluate", str(run), "--metric", "no-such-metric", "--no-progress"]) == 2
    assert "unknown metric 'no-such-metric'" in capsys.readouterr().err


def test_the_console_table_shows_the_metric_plugins_rows():
    from mmcsplat.cli.evaluate import table

    lines = table({"val_masked_psnr": 25.0, "metrics": ["mae"], "val_masked_mae": 0.1, "val_mae": 0.2, "train_masked_mae": 0.05, "train_mae": 0.06})
    assert [line.split()[0] for line in lines] == ["val_masked_psnr", "val_masked_mae", "val_mae", "train_masked_mae", "train_mae"]
