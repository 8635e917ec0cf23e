"""Issue 27's tracking ablation: synthetic study sessions with a motion variant, the optical flow computed
once per session for the cells whose dynamics reads it (and its prediction recorded), the carried joints'
error and seconds per frame in the results, and the built-in study."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from fitting_scene import write_session

import mmcsplat.pipeline.flow as flow_module
from mmcsplat.storage.landmark_formats import write_trc
from mmcsplat.storage.session import SessionReader
from mmcsplat.studies.runner import run_study
from mmcsplat.studies.sessions import prepare_session
from mmcsplat.studies.spec import StudyError, expand, load_study

TINY = "frames = 3, cameras = 4, width = 32, height = 24, samples = 1, adult_leg = false"
POSE2SIM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"


def write_study(folder, variants: str, session: str, fold: str = "cam_0") -> str:
    path = folder / "study.toml"
    path.write_text(f'[study]\nname = "tiny"\nfolds = ["{fold}"]\n\n[sessions.capture]\n{session}\n{variants}')
    return str(path)


def iterative(name: str, params: str) -> str:
    return (f'\n[[variant]]\nname = "{name}"\nconfig = "visual-hull-plate"\nrenderer = {{ name = "torch-reference" }}\n'
            'set = { "fit.iterations" = 2, "initializer.visual-hull.num_points" = 300 }\n'
            f'dynamics = {{ name = "iterative", iterations = 1, neighbours = 4, {params} }}\n')


def test_synthetic_sessions_take_a_motion_and_natural_keeps_the_keys_of_before(tmp_path):
    variants = iterative("cv", 'predict = "constant-velocity"')
    kicks = load_study(write_study(tmp_path, variants, f'synthetic = {{ {TINY}, motion = "fast-kicks" }}'))
    assert kicks.sessions[0].synthetic["motion"] == "fast-kicks"
    keys = {}
    for motion in ("", ', motion = "natural"'):
        study = load_study(write_study(tmp_path, variants, f"synthetic = {{ {TINY}{motion} }}"))
        assert "motion" not in study.sessions[0].synthetic  # the default, left out of identities as before it existed
        keys[motion] = expand(study, tmp_path)[0].spec.key
    assert len(set(keys.values())) == 1 and expand(kicks, tmp_path)[0].spec.key not in keys.values()
    with pytest.raises(StudyError, match=r"\[sessions.capture\] synthetic: .*motion"):
        load_study(write_study(tmp_path, variants, f'synthetic = {{ {TINY}, motion = "waltz" }}'))


def test_flow_is_computed_once_for_the_cells_that_read_it(tmp_path, monkeypatch):
    calls = []
    compute = flow_module.compute_flow

    def counted(url, *args, **kwargs):
        calls.append(str(url))
        return compute(url, *args, **kwargs)
    monkeypatch.setattr(flow_module, "compute_flow", counted)
    study = load_study(write_study(tmp_path, iterative("cv", 'predict = "constant-velocity"') + iterative("flow", 'predict = "flow"')
                                   + iterative("flow-loss", 'predict = "constant-velocity", lambda_flow = 0.01'),
                                   f'synthetic = {{ {TINY}, motion = "fast-kicks" }}'))
    assert [cell.spec.flow for cell in expand(study, tmp_path / "out")] == [None, flow_module.DEFAULT_PRESET, flow_module.DEFAULT_PRESET]
    result = run_study(study, tmp_path / "out", workers=0, progress=False)
    assert len(calls) == 1 and flow_module.flow_complete(calls[0])  # one session, two cells reading its flow
    outcomes = {row.cell.variant: row.outcome for row in result.rows}
    assert all(outcome.status == "complete" for outcome in outcomes.values()), {v: o.error for v, o in outcomes.items()}
    predictions = {variant: json.loads((tmp_path / "out" / "cells" / outcome.key / "track.json").read_text())["summary"]["prediction"]
                   for variant, outcome in outcomes.items()}
    assert predictions == {"cv": "constant-velocity", "flow": "flow", "flow-loss": "constant-velocity"}
    assert {variant: outcome.track_prediction for variant, outcome in outcomes.items()} == predictions
    for outcome in outcomes.values():  # the fast kicks move the feet: the carried joints' error where they moved
        assert math.isfinite(outcome.landmark_moving_median_mm) and outcome.landmark_moving_median_mm > 0
        assert outcome.track_wall_s_per_frame > 0
    table = (tmp_path / "out" / "results.md").read_text()
    assert "| Variant | dynamics | prediction | tracking median (mm) |" in table and "| flow | iterative | flow |" in table
    assert "joints that moved > 1 cm (mm)" in table and "tracking (s/frame)" in table
    assert run_study(study, tmp_path / "out", workers=0, progress=False).reused == 3 and len(calls) == 1


def test_a_synthetic_cell_guides_its_track_with_the_projected_true_joints(tmp_path):
    variant = iterative("keypoints", 'predict = "constant-velocity", lambda_keypoints = 0.1, keypoints = { name = "synthetic" }')
    result = run_study(load_study(write_study(tmp_path, variant, f"synthetic = {{ {TINY} }}")), tmp_path / "out", workers=0, progress=False)
    outcome = result.rows[0].outcome
    assert outcome.status == "complete", outcome.error
    summary = json.loads((tmp_path / "out" / "cells" / outcome.key / "track.json").read_text())["summary"]
    guidance = summary["keypoint_guidance"]  # bound to the fit and used, not silently off; the held-out camera left out
    assert guidance["weight"] == 0.1 and guidance["keypoints"] and guidance["cameras"] == ["cam_1", "cam_2", "cam_3"]


def test_a_stored_session_read_in_place_gains_its_flow_and_nothing_else(tmp_path):
    write_session(tmp_path / "scene.zarr", frames=2, plates=True)
    frame = SessionReader(tmp_path / "scene.zarr").frame(1, "cam_1").rgb.copy()
    study = load_study(write_study(tmp_path, iterative("flow", 'predict = "flow"'), 'path = "scene.zarr"'))
    assert expand(study, tmp_path / "out")[0].plan.in_place
    result = run_study(study, tmp_path / "out", workers=0, progress=False)
    assert result.rows[0].outcome.track_prediction == "flow", result.rows[0].outcome.error
    assert flow_module.flow_complete(tmp_path / "scene.zarr") and (SessionReader(tmp_path / "scene.zarr").frame(1, "cam_1").rgb == frame).all()


def test_a_capture_session_finds_todays_pose2sim_keypoints_and_joints_as_run_does(tmp_path):
    capture = tmp_path / "capture"
    (capture / "pose" / "cam01_json").mkdir(parents=True)
    (capture / "pose-3d").mkdir()
    write_trc(capture / "pose-3d" / "trial_0-100.trc", ["Neck"], np.arange(2) / 60, np.zeros((2, 1, 3)), 60)
    study = load_study(write_study(tmp_path, iterative("flow", 'predict = "flow"'), 'capture = { path = "capture" }'))
    settings = study.sessions[0].capture
    assert settings["keypoints"] == str(capture / "pose") and settings["joints"] == str(capture / "pose-3d" / "trial_0-100.trc")


def test_a_capture_session_fills_in_what_run_would_and_refuses_what_does_not_apply(tmp_path, monkeypatch):
    capture = tmp_path / "capture"
    (capture / "pose_2d").mkdir(parents=True)
    write_trc(capture / "joints.trc", ["Neck"], np.arange(2) / 60, np.zeros((2, 1, 3)), 60)
    variants = iterative("flow", 'predict = "flow"')
    study = load_study(write_study(tmp_path, variants, 'capture = { path = "capture", frames = [0, 4], holdout = ["cam_04"] }'))
    settings = study.sessions[0].capture
    assert settings["scale"] == "auto" and settings["frames"] == [0, 4] and settings["holdout"] == ["cam_04"]  # run's scale
    assert settings["keypoints"] == str(capture / "pose_2d") and settings["joints"] == str(capture / "joints.trc")
    cell = expand(study, tmp_path / "out")[0]
    assert cell.spec.joints == str(capture / "joints.trc") and "joints" not in cell.plan.identity["capture"]
    assert "reader" not in cell.plan.identity["capture"]  # given only: the cells of studies made before keep their keys
    assert cell.plan.url.startswith(str(tmp_path / "out" / "sessions" / "capture" / "capture-")) and not cell.plan.in_place
    with pytest.raises(StudyError, match=r"\['cameras'\] do not apply to a capture session"):
        load_study(write_study(tmp_path, variants, 'capture = { path = "capture" }\ncameras = ["cam_01"]'))
    # Metres unless stated (the units are in every cell's key); run's auto when asked; nothing else.
    assert settings["units"] == "m"
    assert load_study(write_study(tmp_path, variants, 'capture = { path = "capture", units = "auto" }')).sessions[0].capture["units"] == "auto"
    with pytest.raises(StudyError, match=r"capture units must be one of auto, m, mm, got 'cm'"):
        load_study(write_study(tmp_path, variants, 'capture = { path = "capture", units = "cm" }'))
    # A segmenter makes the capture's masks, as `run --segmenter` does: another session, made with it.
    segmented = expand(load_study(write_study(tmp_path, variants, 'capture = { path = "capture", frames = [0, 4], holdout = ["cam_04"] }\n'
                                              'segmenter = { name = "background", method = "median" }')), tmp_path / "out")[0]
    assert segmented.plan.identity["segmenter"] == {"name": "background", "params": {"method": "median"}}
    assert segmented.plan.url != cell.plan.url and segmented.plan.identity["capture"] == cell.plan.identity["capture"]
    (capture / "pose_2d" / "cam_01").mkdir()
    (capture / "pose_2d" / "cam_01" / "frame_0.json").write_text("{}")  # an OpenPose folder, read by the session's maker only
    made = {}
    monkeypatch.setattr("mmcsplat.pipeline.capture_session.prepare_capture_session",
                        lambda capture, partial, **kwargs: (partial.mkdir(parents=True), made.update(kwargs)))
    prepare_session(segmented.plan, progress=False)
    assert made["segmenter"].name == "background" and made["segmenter"].plugin.method == "median"
    prepare_session(cell.plan, progress=False)
    assert made["segmenter"] is None
    with pytest.raises(StudyError, match="capture path .*elsewhere is not a folder"):
        load_study(write_study(tmp_path, variants, 'capture = { path = "elsewhere" }'))
    with pytest.raises(StudyError, match="unknown capture key"):
        load_study(write_study(tmp_path, variants, 'capture = { path = "capture", fps = 30 }'))


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared real data not found at {POSE2SIM}")
def test_a_pose2sim_capture_cell_tracks_with_flow_and_scores_its_joints_against_the_trc(tmp_path):
    session = (f'capture = {{ path = "{POSE2SIM}", calibration = "{POSE2SIM / "Calib_qualisys.toml"}", scale = 0.125, frames = [0, 3], '
               'holdout = ["cam_04"] }')
    variant = ('[[variant]]\nname = "flow"\nconfig = "visual-hull-plate"\nset = { "fit.iterations" = 60 }\n'
               'dynamics = { name = "iterative", iterations = 2, predict = "flow" }\n')
    result = run_study(load_study(write_study(tmp_path, variant, session, fold="cam_04")), tmp_path / "out", workers=0, progress=False)
    outcome = result.rows[0].outcome
    assert outcome.status == "complete", outcome.error
    reader = SessionReader(result.rows[0].cell.plan.url)  # masks from the keypoints, plates estimated: as `mmcsplat run` makes it
    assert reader.has("mask") and all(reader.plate_source(name)["kind"] == "estimated" for name in reader.camera_names)
    assert outcome.track_prediction == "flow" and math.isfinite(outcome.landmark_median_mm) and outcome.track_wall_s_per_frame > 0


def test_builtin_tracking_ablation_adds_one_option_a_row():
    study = load_study("tracking-ablation")
    assert [variant.name for variant in study.variants] == ["constant-velocity", "+ flow prediction", "+ flow loss", "+ coarse to fine",
                                                            "+ keypoints"]
    options = [variant.config.plugin("dynamics").params for variant in study.variants]
    assert [params["predict"] for params in options] == ["constant-velocity", "flow", "flow", "flow", "flow"]
    assert [params.get("lambda_flow", 0) for params in options] == [0, 0, 0.01, 0.01, 0.01]
    assert [params.get("coarse_iterations", 0) for params in options] == [0, 0, 0, 10, 10]
    assert [params.get("lambda_keypoints", 0) for params in options] == [0, 0, 0, 0, 0.1]
    assert options[-1]["keypoints"] == {"name": "synthetic"}  # the synthetic capture's projected true joints
    assert study.sessions[0].synthetic["motion"] == "fast-kicks"
    assert [cell.spec.flow for cell in expand(study, "out")] == [None, *[flow_module.DEFAULT_PRESET] * 4]


def test_a_pool_workers_warnings_are_one_line_as_the_studys_own(tmp_path, capfd):
    """Cells run in spawned workers print their warnings as the command does, ``mmcsplat compare: warning: …``,
    not in Python's two-line form (the format was the study's process's alone)."""
    from mmcsplat.cli.main import main

    variant = ('\n[[variant]]\nname = "fit"\nconfig = "visual-hull"\nrenderer = { name = "torch-reference" }\n'
               'set = { "fit.iterations" = 2, "initializer.visual-hull.num_points" = 200 }\n')
    study = write_study(tmp_path, variant, f"synthetic = {{ {TINY} }}")  # four cameras, one held out: three train
    assert main(["compare", study, "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"]) == 0
    err = capfd.readouterr().err
    assert "mmcsplat compare: warning: only 3 training cameras" in err and "UserWarning" not in err


def test_a_synthetic_session_whose_held_out_cameras_change_is_ingested_again(tmp_path):
    """The synthesized capture is kept when only the held-out cameras change, but its ingest holds them out: a cell
    of the new held-out camera ran on the old one's session, its results scored on the old camera."""
    variants = iterative("cv", 'predict = "constant-velocity"')
    for heldout in ("cam_0", "cam_2"):
        study = load_study(write_study(tmp_path, variants, f'synthetic = {{ {TINY} }}\nheldout = ["{heldout}"]', fold=heldout))
        cell = expand(study, tmp_path / "out")[0]
        prepare_session(cell.plan, progress=False)
        assert SessionReader(cell.plan.url).heldout == (heldout,)


def test_a_capture_session_starts_where_a_trimmed_trcs_joints_start(tmp_path):
    """As run does: a TRC of a trimmed trial (today's Pose2Sim, OrigDataStartFrame 3) starts the capture session's
    frames there, so its cells' fitted frame has joints; frames given that start before it are refused."""
    capture = tmp_path / "capture"
    (capture / "pose_2d").mkdir(parents=True)
    write_trc(capture / "trial_3-10.trc", ["Neck"], (3 + np.arange(7)) / 60, np.zeros((7, 1, 3)), 60, first_frame=3)
    variants = iterative("flow", 'predict = "flow"')
    assert load_study(write_study(tmp_path, variants, 'capture = { path = "capture" }')).sessions[0].capture["frames"] == [3, None]
    assert load_study(write_study(tmp_path, variants, 'capture = { path = "capture", frames = [4, 9] }')).sessions[0].capture["frames"] == [4, 9]
    with pytest.raises(StudyError, match=r"capture: frames \[0, 9\]: the joints .* start at the capture's frame 3 .*: start the frames at 3"):
        load_study(write_study(tmp_path, variants, 'capture = { path = "capture", frames = [0, 9] }'))
    with pytest.raises(StudyError, match=r"frames must be \[start, stop\]"):  # one number was read as the stop
        load_study(write_study(tmp_path, variants, 'capture = { path = "capture", frames = [4] }'))


def test_a_stop_while_a_studys_results_are_written_leaves_them_all_new(tmp_path, monkeypatch):
    """results.json, .csv and .md describe the same cells: Ctrl-C after the tables waits until results.md is written
    too (a stop there left a variant in results.json that results.md and `mmcsplat report` did not show)."""
    import os
    import signal

    import mmcsplat.studies.runner as runner

    written = runner.write_tables

    def then_stop(out, *args, **kwargs):
        written(out, *args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(runner, "write_tables", then_stop)
    study = load_study(write_study(tmp_path, iterative("cv", 'predict = "constant-velocity"'), f"synthetic = {{ {TINY} }}"))
    with pytest.raises(KeyboardInterrupt):
        run_study(study, tmp_path / "out", workers=0, progress=False)
    assert "cv" in (tmp_path / "out" / "results.md").read_text()
