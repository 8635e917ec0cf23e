"""The step runner of the demo, `mmcsplat run` and study cells: steps skipped when done, the settings record
written only once a step has succeeded (issue 25), stores made in a hidden sibling renamed into place."""

from __future__ import annotations

import json

import attrs
import pytest

from mmcsplat.configuration.config import ConfigError
from mmcsplat.jobs.capture import SETTINGS_FILE, CaptureSettings, run_capture
from mmcsplat.pipeline.steps import SettingsRecord, Step, fit_complete, made_in_place, run_steps
from mmcsplat.plugin_api.errors import InputError


@attrs.frozen
class Settings:
    size: int = 1


def test_steps_run_in_order_and_done_ones_are_skipped(tmp_path):
    made, lines = [], []
    steps = [Step("first", lambda: True, lambda: made.append("first")),
             Step("second", lambda: "first" in made or (tmp_path / "x").exists(), lambda: made.append("second")),
             Step("third", lambda: False, lambda: (tmp_path / "x").touch())]
    times = run_steps("job", steps, lines.append)
    assert made == ["second"] and [step.reused for step in times] == [True, False, False]
    assert [line.split(" (")[0] for line in lines] == ["[job] first already done", "[job] second done", "[job] third done"]
    assert [step.reused for step in run_steps("job", steps)] == [True, True, False]  # asked when its turn comes


def test_the_settings_are_recorded_once_a_step_succeeded(tmp_path):
    record = SettingsRecord.of(tmp_path / "job.json", Settings(1))

    def fail() -> None:
        raise InputError("the first step failed")

    with pytest.raises(InputError, match="first step failed"):
        run_steps("job", [Step("a", lambda: False, fail)], record=record)
    assert not record.path.exists()  # nothing was made: other settings may go ahead
    other = SettingsRecord.of(tmp_path / "job.json", Settings(2))
    run_steps("job", [Step("a", lambda: False, lambda: None)], record=other)
    assert json.loads(other.path.read_text()) == {"size": 2}
    with pytest.raises(InputError, match=r"job.json: size 2, now 1\): use another --out"):
        run_steps("job", [Step("a", lambda: True, lambda: None)], record=record)


def test_a_failed_first_run_does_not_lock_its_out_to_its_settings(tmp_path):
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()  # no videos, no calibration: ingest fails
    for settings in (CaptureSettings(scale=0.5), CaptureSettings()):
        with pytest.raises(InputError) as failed:
            run_capture(capture, out, settings, progress=False, log=lambda _: None)
        assert "other settings" not in str(failed.value)
        assert not out.exists()  # no reader recognises the folder: refused before anything is made


def test_a_folder_made_before_a_setting_existed_resumes_when_its_value_is_unchanged(tmp_path):
    made = CaptureSettings()
    old = {key: value for key, value in json.loads(json.dumps(attrs.asdict(made))).items() if key not in ("reader_options", "track_flow_gain")}
    (tmp_path / SETTINGS_FILE).write_text(json.dumps(old))
    with pytest.raises(InputError, match=r"track_flow_gain 1.0, now 2.0\)"):  # before the setting, tracking used the plugin's 1
        SettingsRecord.of(tmp_path / SETTINGS_FILE, made).check()
    SettingsRecord.of(tmp_path / SETTINGS_FILE, CaptureSettings(track_flow_gain=1.0)).check()  # reader_options () as before
    with pytest.raises(InputError, match=r"reader_options \[\], now \['size_mismatch=crop'\]"):
        SettingsRecord.of(tmp_path / SETTINGS_FILE, CaptureSettings(track_flow_gain=1.0, reader_options=("size_mismatch=crop",))).check()
    (tmp_path / "job.json").write_text("{}")
    with pytest.raises(InputError, match="size None, now 1"):  # a setting with no before value is taken as changed
        SettingsRecord.of(tmp_path / "job.json", Settings(1)).check()


def test_a_store_appears_whole_or_not_at_all(tmp_path):
    target = tmp_path / "store"

    def interrupted(partial):
        partial.mkdir()
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        made_in_place(target, interrupted)
    assert list(tmp_path.iterdir()) == []  # neither the target nor its partial sibling
    (tmp_path / ".store.partial").mkdir()  # a leftover from a killed process
    made_in_place(target, lambda partial: (partial.mkdir(), (partial / "data").write_text("x")))  # the leftover is replaced
    assert (target / "data").read_text() == "x" and sorted(path.name for path in tmp_path.iterdir()) == ["store"]
    assert not fit_complete(tmp_path)


def test_an_error_of_a_store_made_in_place_names_the_store_not_its_hidden_partial(tmp_path):
    target = tmp_path / "store"

    def refused(partial):
        raise ConfigError(f"{partial / 'images'}: damaged")

    with pytest.raises(ConfigError, match=rf"^{target / 'images'}: damaged$") as raised:  # the same type, for callers catching it
        made_in_place(target, refused)
    assert ".store.partial" not in str(raised.value) and isinstance(raised.value.__cause__, ConfigError)
    elsewhere = InputError("another file: damaged")

    def failed(partial):
        raise elsewhere

    with pytest.raises(InputError) as raised:
        made_in_place(target, failed)
    assert raised.value is elsewhere and list(tmp_path.iterdir()) == []
