"""run.json through RunInfo: old records read, bad ones named, newer versions refused."""

from __future__ import annotations

import json

import pytest

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.storage.run_info import RUN_INFO, RUN_INFO_VERSION, RunInfo

VERSION_0 = {  # a run.json as fits wrote it before the version field
    "status": "complete", "error": None, "warnings": [], "session": "/data/session.zarr", "config": "masked",
    "config_values": {"fit": {"iterations": 10}}, "renderer": "torch-cpu", "frame": 0, "train_cameras": ["cam_1", "cam_2"],
    "heldout_cameras": ["cam_0"], "iterations": 10, "num_gaussians": 5, "wall_s": 1.5, "loss_min": 0.1, "loss_final": 0.2,
    "scene_center": [0, 0, 0], "scene_scale": 1.0,
}


def test_a_version_0_record_reads_with_the_defaults_of_its_time(tmp_path):
    (tmp_path / RUN_INFO).write_text(json.dumps(VERSION_0))
    info = RunInfo.read(tmp_path)
    assert info.complete and info.train_cameras == ("cam_1", "cam_2") and info.scene_center == (0.0, 0.0, 0.0)
    assert info.supersample == 1 and info.background_value == (0.0, 0.0, 0.0) and info.resumed_from is None
    info.write(tmp_path)
    again = json.loads((tmp_path / RUN_INFO).read_text())
    assert again["version"] == RUN_INFO_VERSION and again["train_cameras"] == ["cam_1", "cam_2"]
    assert RunInfo.read(tmp_path) == info


@pytest.mark.parametrize("content, message", [
    ("{not json", "not readable JSON"),
    (json.dumps([1, 2]), "expected a JSON object"),
    (json.dumps({k: v for k, v in VERSION_0.items() if k != "train_cameras"}), "missing train_cameras"),
    (json.dumps(VERSION_0 | {"status": "finished"}), "not a valid run record"),
    (json.dumps(VERSION_0 | {"version": RUN_INFO_VERSION + 1}), "newer than this mmcsplat reads"),
])
def test_a_bad_record_is_one_error_naming_the_file(tmp_path, content, message):
    (tmp_path / RUN_INFO).write_text(content)
    with pytest.raises(InputError, match=message) as caught:
        RunInfo.read(tmp_path)
    assert str(tmp_path / RUN_INFO) in str(caught.value)


def test_a_missing_record_names_the_run(tmp_path):
    with pytest.raises(MissingFileError, match="not a fit run directory"):
        RunInfo.read(tmp_path)


def test_a_project_folder_moved_whole_still_finds_its_session(tmp_path):
    project = tmp_path / "project"
    (project / "run").mkdir(parents=True)
    RunInfo.from_json(VERSION_0 | {"session": str(project / "s.zarr")}, "test").write(project / "run")
    assert json.loads((project / "run" / RUN_INFO).read_text())["session"] == "../s.zarr"
    moved = tmp_path / "elsewhere"
    project.rename(moved)
    assert RunInfo.read(moved / "run").session == str(moved / "s.zarr")
    RunInfo.from_json(VERSION_0 | {"session": "s3://bucket/s.zarr"}, "test").write(moved / "run")  # URLs stay as they are
    assert RunInfo.read(moved / "run").session == "s3://bucket/s.zarr"
