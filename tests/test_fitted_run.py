"""FittedRun: a run directory's first-frame fit read once — its record, parameters, colour correction,
settings, session and backdrops — with errors that name the directory."""

from __future__ import annotations

import json

import pytest
import torch
from fitting_scene import write_fitted_run, write_session

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.run import RUN_INFO
from mmcsplat.training.fitted_run import FittedRun


def test_a_fitted_run_reads_back_whole(tmp_path):
    session = write_session(tmp_path / "s.zarr", cameras=3)
    run = write_fitted_run(tmp_path / "run", session, background=[0.0, 0.5, 1.0], supersample=2)
    fitted = FittedRun.load(run)
    assert fitted.info.complete and fitted.session.url == str(session.resolve())
    assert fitted.params["means"].shape == (fitted.info.num_gaussians, 3)
    assert fitted.camera_scale.shape[0] == len(fitted.info.train_cameras) == fitted.camera_offset.shape[0]
    assert fitted.settings.supersample == 2 and fitted.background == (0.0, 0.5, 1.0)
    assert torch.equal(fitted.backdrop("cam_1"), torch.tensor([0.0, 0.5, 1.0]))
    fitted.require_complete()


def test_what_is_not_a_complete_fit_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=f"{tmp_path} is not a fit run directory"):
        FittedRun.load(tmp_path)
    run = write_fitted_run(tmp_path / "run", write_session(tmp_path / "s.zarr", cameras=3))
    record = json.loads((run / RUN_INFO).read_text()) | {"status": "running", "session": str(tmp_path / "gone.zarr")}
    (run / RUN_INFO).write_text(json.dumps(record))
    fitted = FittedRun.load(run)  # the session is opened only when needed
    with pytest.raises(InputError, match="the first-frame fit is 'running', not complete"):
        fitted.require_complete()
    with pytest.raises(FileNotFoundError, match="its session .*gone.zarr cannot be opened"):
        fitted.session
