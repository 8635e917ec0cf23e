"""``mmcsplat run`` on a synthetic capture with nothing but its videos, calibration and ground truth (no
plates, no keypoints, no masks it fits on): the masks come from ``parallax``, and the capture's true joints
are carried, hold the body's parts and are scored, as a TRC's would be. docs/real-data.md has the
full-size figures. The same run then resumes under the other spelling of its scale."""

from __future__ import annotations

import json
import shutil
from contextlib import redirect_stdout
from io import StringIO

import numpy as np
import pytest

from mmcsplat.cli import main
from mmcsplat.jobs.capture import SETTINGS_FILE
from mmcsplat.synthetic import SynthConfig, synthesize

ARGUMENTS = ["--set", "fit.iterations=60", "--track-iterations", "5", "--no-progress"]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The capture and the folder of one ``mmcsplat run`` at the default scale (``auto``: 1 at this size), and what it printed."""
    root = tmp_path_factory.mktemp("run_synthetic")
    capture = synthesize(root / "capture", SynthConfig(frames=4, cameras=6, width=128, height=96, seed=0), progress=False).out_dir
    shutil.rmtree(capture / "plates")  # nothing but videos, calibration and the ground truth
    out = root / "out"
    with redirect_stdout(StringIO()) as printed:
        assert main(["run", str(capture), "--out", str(out), *ARGUMENTS]) == 0
    return capture, out, printed.getvalue()


def test_run_carries_and_scores_a_synthetic_captures_true_joints(made):
    capture, out, printed = made
    truth = str((capture / "ground_truth.zarr").resolve())
    assert "joints: median 3D error" in printed and f"against the synthetic joints {truth}" in printed
    assert json.loads((out / "masks.json").read_text())["masks"] == "parallax"
    track = json.loads((out / "run" / "track.json").read_text())
    assert track["params"]["skeleton"] == {"name": "synthetic", "path": truth}
    assert "elbow_left–wrist_left" in track["summary"]["body_parts"]["parts"]
    info = json.loads((out / "run" / "landmarks.json").read_text())
    assert info["source"] == "synthetic" and len(info["names"]) == 14 and not info["unbound"]
    # A few centimetres at worst at this size and with these few steps; the full-size run is at 2 mm (docs/real-data.md).
    assert 0 < info["accuracy_3d"]["median_mm"] < 30


def test_a_folder_resumes_under_auto_where_auto_gives_the_scale_it_was_made_with(made, capsys):
    capture, out, _ = made
    record = out / SETTINGS_FILE
    assert json.loads(record.read_text())["scale"] == "auto"
    for spelled in (["--scale", "1"], []):  # made with auto, resumed with its number; then made with the number, resumed with auto
        with redirect_stdout(StringIO()) as printed:
            assert main(["run", str(capture), "--out", str(out), *spelled, *ARGUMENTS]) == 0
        assert "first-frame fit already done" in printed.getvalue() and "track (iterative) already done" in printed.getvalue()
        record.write_text(json.dumps({**json.loads(record.read_text()), "scale": 1.0}))  # as a folder made before `auto` records it
    capsys.readouterr()
    assert main(["run", str(capture), "--out", str(out), "--scale", "0.5", *ARGUMENTS]) == 2  # another scale is still refused
    refused = capsys.readouterr().err
    assert "was made with other settings" in refused and "scale 1.0, now 0.5" in refused


def test_a_folder_resumes_under_auto_units_where_its_rig_reads_in_the_units_it_was_made_with(made, capsys):
    capture, out, _ = made
    record = out / SETTINGS_FILE
    made_with = json.loads(record.read_text())
    assert made_with["units"] == "auto"
    try:
        for spelled in (["--units", "m"], []):  # made with auto, resumed with metres; then made with metres, resumed with auto
            with redirect_stdout(StringIO()) as printed:
                assert main(["run", str(capture), "--out", str(out), *spelled, *ARGUMENTS]) == 0
            assert "track (iterative) already done" in printed.getvalue()
            record.write_text(json.dumps({**made_with, "units": "m"}))  # as a folder made before `auto` records it
        capsys.readouterr()
        assert main(["run", str(capture), "--out", str(out), "--units", "mm", *ARGUMENTS]) == 2
        assert "units 'm', now 'mm'" in capsys.readouterr().err
    finally:
        record.write_text(json.dumps(made_with))


def test_run_reads_a_calibration_in_millimetres_and_says_so(made, tmp_path):
    from mmcsplat.storage.calibration import read_calibration, write_calibration
    from mmcsplat.storage.session import SessionReader

    capture, _, _ = made
    copy = tmp_path / "capture"
    shutil.copytree(capture, copy)
    metres = read_calibration(copy / "calibration.toml")
    write_calibration(copy / "calibration.toml", metres, units="mm")
    out = tmp_path / "out"
    with redirect_stdout(StringIO()) as printed:
        assert main(["run", str(copy), "--out", str(out), "--frames", "0:3", "--set", "fit.iterations=10", "--track-iterations", "1",
                     "--no-progress"]) == 0
    assert "calibration read in mm" in printed.getvalue()
    session = SessionReader(out / "session.zarr")
    for camera in metres:
        np.testing.assert_allclose(session.camera(camera.name).center, camera.center, atol=1e-9)


def test_a_folder_made_at_another_scale_than_auto_gives_is_refused_under_auto(made, tmp_path, capsys):
    capture, _, _ = made
    out = tmp_path / "half"
    with redirect_stdout(StringIO()):
        assert main(["run", str(capture), "--out", str(out), "--scale", "0.5", "--set", "fit.iterations=10", "--track-iterations", "1",
                     "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["run", str(capture), "--out", str(out), "--set", "fit.iterations=10", "--track-iterations", "1", "--no-progress"]) == 2
    assert "scale 0.5, now 'auto'" in capsys.readouterr().err  # auto gives 1 here, not the 0.5 its session was stored at


def test_a_folder_resumes_under_auto_iterations_where_auto_gives_the_steps_it_was_tracked_with(made, capsys):
    capture, out, _ = made
    record = out / SETTINGS_FILE
    made_with = json.loads(record.read_text())
    assert made_with["track_iterations"] == 5
    others = [argument for argument in ARGUMENTS if argument not in ("--track-iterations", "5")]
    assert main(["run", str(capture), "--out", str(out), *others]) == 2  # auto gives 100 at the capture's 30 fps, not 5
    assert "track_iterations 5, now 'auto'" in capsys.readouterr().err
    record.write_text(json.dumps({**made_with, "track_iterations": 100}))  # as if tracked at what auto gives
    try:
        with redirect_stdout(StringIO()) as printed:
            assert main(["run", str(capture), "--out", str(out), *others]) == 0
        assert "track (iterative) already done" in printed.getvalue()
    finally:
        record.write_text(json.dumps(made_with))


def test_only_errors_of_the_masks_carry_advice_on_motion_masks(made, tmp_path, monkeypatch, capsys):
    """A fit on ``parallax`` masks that fails because of them says how to get better masks; any other error
    of the fit (here a stand-in for a camera missing from the fitted frame) reaches the user as raised."""
    from mmcsplat.pipeline.fit import FirstFrameFit
    from mmcsplat.plugin_api.errors import InputError, SubjectMaskError

    capture, _, _ = made
    for error, advised in ((SubjectMaskError("no point lies inside every view's mask"), True),
                           (InputError("frame 0 of camera 'cam_1' is not in the session"), False)):
        def failing(self, error=error):
            raise error

        monkeypatch.setattr(FirstFrameFit, "run", failing)
        with redirect_stdout(StringIO()):
            assert main(["run", str(capture), "--out", str(tmp_path / "out"), *ARGUMENTS]) == 2
        said = capsys.readouterr().err
        assert str(error) in said and ("the masks come from the subject's motion" in said) == advised


def test_run_tracks_with_the_dynamics_method_its_configuration_names(made, tmp_path, capsys):
    """A configuration naming another dynamics method (a third party's, or deformation) is tracked with it, as
    configured: before, run forced `iterative` over the table, which then refused the table's parameters."""
    capture, _, _ = made
    out = tmp_path / "deformed"
    settings = ["--set", "fit.iterations=20", "--set", "dynamics.name=deformation", "--set", "dynamics.iterations=8",
                "--set", "dynamics.width=16", "--no-progress"]
    with redirect_stdout(StringIO()) as printed:
        assert main(["run", str(capture), "--out", str(out), *settings]) == 0
    assert "run: tracking with 'deformation', as the configuration's [dynamics] table sets it" in printed.getvalue()
    assert "[run] track (deformation) done" in printed.getvalue()
    track = json.loads((out / "run" / "track.json").read_text())
    assert track["method"] == "deformation" and track["params"]["iterations"] == 8
    assert main(["run", str(capture), "--out", str(tmp_path / "guided"), *settings, "--track-keypoints", "1"]) == 2
    assert "--track-keypoints guides the iterative tracker; visual-hull-plate tracks with 'deformation'" in capsys.readouterr().err
