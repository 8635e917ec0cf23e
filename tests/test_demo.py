"""mmcsplat demo: the main job end to end at a tiny size, its summary, and its resume on a rerun."""

from __future__ import annotations

import json
import re
from contextlib import redirect_stdout
from io import StringIO

import pytest

from mmcsplat.analysis.lost_landmarks import lost_line
from mmcsplat.cli import main
from mmcsplat.configuration.config import load_config
from mmcsplat.jobs.demo import DEMO_ITERATIONS, DemoPaths, tracking_choice

TINY = ["--num-frames", "3", "--width", "64", "--height", "48", "--track-iterations", "2", "--no-progress",
        "--set", "fit.iterations=10"]  # fmt: skip
STEPS = ("synthesize", "ingest + segment", "first-frame fit", "track (iterative)", "evaluate", "landmarks",
         "render trajectories", "render landmarks", "render novel view", "report")  # fmt: skip


def ran(output: str) -> dict[str, bool]:
    """Step name → whether this run did it (False: already done)."""
    return {name: status == "done" for name, status in re.findall(r"^\[demo\] (.+?) (already done|done) \(", output, flags=re.M)}


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """(output folder, the first run's stdout)."""
    out = tmp_path_factory.mktemp("demo") / "out"
    with redirect_stdout(StringIO()) as captured:
        assert main(["demo", "--out", str(out), *TINY]) == 0
    return out, captured.getvalue()


def test_demo_writes_every_output_and_names_it(demo):
    out, output = demo
    assert ran(output) == dict.fromkeys(STEPS, True)
    paths = DemoPaths.under(out.resolve())
    outputs = [paths.capture / "calibration.toml", paths.capture / "ground_truth.zarr", paths.session, paths.run / "run.json",
               paths.tracks, paths.track_info, paths.metrics, paths.landmarks_csv, paths.landmarks_info, paths.landmarks_trc,
               paths.movement, paths.run / "movement.csv", paths.trajectories_video, paths.trajectories_strip, paths.landmarks_video, paths.novel, paths.report]  # fmt: skip
    assert [path for path in outputs if not path.exists()] == []
    summary = output[output.index("mmcsplat demo finished"):]
    for path in (paths.capture, paths.session, paths.run, paths.tracks, paths.metrics, paths.landmarks_csv, paths.landmarks_trc,
                 paths.movement, paths.trajectories_video, paths.trajectories_strip, paths.landmarks_video, paths.novel, paths.report):  # fmt: skip
        assert f" {path}\n" in summary + "\n", path
    assert "iterative, 2 iterations per frame" in summary
    metrics = json.loads(paths.metrics.read_text())
    assert metrics["tracking_method"] == "iterative" and len(metrics["per_frame_val_masked_psnr"]) == 3
    assert f"masked PSNR {metrics['val_masked_psnr']:.2f} dB" in summary
    assert f"median {metrics['tracking_median_mm']:.2f} mm" in summary and f"90th percentile {metrics['tracking_p90_mm']:.2f} mm" in summary
    assert f"\n  {metrics['drift_summary']}\n" in summary and metrics["drift_summary"].startswith(("drift: ", "no drift: "))
    assert f"\n  {lost_line(json.loads(paths.landmarks_info.read_text())['lost'])}\n" in summary
    for name in STEPS:
        assert f"    {name} " in summary
    assert json.loads(paths.track_info.read_text())["params"]["iterations"] == 2
    assert json.loads((paths.run / "run.json").read_text())["config_values"]["dynamics"] == {"iterations": 2}  # `track RUN` re-tracks alike
    landmarks = json.loads(paths.landmarks_info.read_text())
    assert landmarks["source"] == "synthetic" and len(landmarks["names"]) == 14
    assert landmarks["bind_frames"] == 1  # exact joints: bound at the fitted frame alone
    moving = landmarks["accuracy_3d"]["moving_median_mm"]
    assert f"median error {'n/a' if moving is None else f'{moving:.1f} mm'}" in summary
    movement = json.loads(paths.movement.read_text())  # the synthetic infant's joints have every angle's landmarks
    assert movement["joint_angles_left_out"] == {} and len(movement["joint_angles"]) == 8
    assert all(len(angle["per_frame_deg"]) == 3 for angle in movement["joint_angles"].values())


def test_rerun_skips_done_steps_and_redoes_stale_ones(demo, capsys):
    out, _ = demo
    assert main(["demo", "--out", str(out), *TINY]) == 0
    assert ran(capsys.readouterr().out) == dict.fromkeys(STEPS, False)
    paths = DemoPaths.under(out.resolve())
    paths.novel.unlink()  # the report embeds it: both are made again, nothing else
    assert main(["demo", "--out", str(out), *TINY]) == 0
    assert ran(capsys.readouterr().out) == {name: name in ("render novel view", "report") for name in STEPS}
    assert paths.novel.exists()


def test_rerun_with_other_settings_is_refused(demo, capsys):
    out, _ = demo
    assert main(["demo", "--out", str(out), *TINY, "--track-iterations", "3"]) == 2
    error = capsys.readouterr().err
    assert "demo.json" in error and "track_iterations 2, now 3" in error


def test_tracking_iterations_come_from_option_then_table_then_default():
    bare = load_config("paper-masked")
    assert tracking_choice(bare, None) == ("iterative", [f"dynamics.iterations={DEMO_ITERATIONS}"])  # not auto's 100 at 30 fps
    assert tracking_choice(bare, 7) == ("iterative", ["dynamics.iterations=7"])
    table = load_config("paper-masked", ["dynamics.name=iterative", "dynamics.iterations=40", "dynamics.means_lr=0.002"])
    assert tracking_choice(table, None) == ("iterative", [])  # the table's settings, kept by the tracking step
    assert tracking_choice(table, 7) == ("iterative", ["dynamics.iterations=7"])
    other = load_config("paper-masked", ["dynamics.name=deformation"])
    assert tracking_choice(other, None) == ("deformation", [])
    with pytest.raises(ValueError, match="chooses 'deformation'"):
        tracking_choice(other, 7)
