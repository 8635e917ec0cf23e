"""Reliability, class 3: names read from files become path components only when they are plain names,
so nothing is written outside the output folder."""

from __future__ import annotations

import pytest

from mmcsplat.cli.main import main


@pytest.mark.parametrize("name", ["../../../escaped", "/tmp/absolute", "a/b", ".hidden"])
def test_a_study_name_cannot_leave_the_output_folder(tmp_path, capsys, name):
    study = tmp_path / "study.toml"
    study.write_text(f'[sessions."{name}"]\nsynthetic = {{}}\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n')
    out = tmp_path / "deep" / "er" / "out"
    assert main(["compare", str(study), "--out", str(out), "--dry-run"]) == 2
    assert "a session name becomes a folder under --out" in capsys.readouterr().err
    assert not (tmp_path / "escaped").exists() and not (tmp_path / "deep").exists()
