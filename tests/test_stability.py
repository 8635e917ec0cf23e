"""Stability runs: the failure regimes (unmasked random start, three cameras, one camera's wrong
extrinsics, the subject leaving the view, a diverging fit, a loss blowing up) are each detected and
reported, the study completes, and the stability table's fractions are right."""

from __future__ import annotations

import json

import pytest
from fitting_scene import write_session

from mmcsplat.cli import main
from mmcsplat.storage.session import SessionReader
from mmcsplat.studies.cells import CellOutcome
from mmcsplat.studies.spec import StudyError, load_study
from mmcsplat.studies.stability import AGREEMENT_THRESHOLD, BLOWUP_FACTOR, FLOATER_THRESHOLD, GAP_DB, classify, run_stability

FIT = """
[fit]
iterations = {iterations}
checkpoint_every = 100
lambda_seg = 3.0

[renderer]
name = "torch-reference"
"""
HULL = FIT + """
[[initializer]]
name = "visual-hull"
num_points = 150
half_size = 0.3

[[initializer]]
name = "masked"
"""
# paper-unmasked, shrunk: random points over a 2 m cube, the image loss sees the whole image.
UNMASKED = FIT + """
[[initializer]]
name = "random"
num_points = 300
half_size = 1.0
"""


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The fitting scene's session and the tiny configurations the studies name."""
    folder = tmp_path_factory.mktemp("stability")
    write_session(folder / "scene.zarr")
    (folder / "hull.toml").write_text(HULL.format(iterations=6))
    (folder / "unmasked.toml").write_text(UNMASKED.format(iterations=6))
    (folder / "short.toml").write_text(HULL.format(iterations=2))
    return folder


def write_study(folder, name: str, sessions: str, variants: str) -> str:
    path = folder / f"study-{name}.toml"
    path.write_text(f'[study]\nname = "{name}"\nfolds = ["cam_0"]\n\n{sessions}\n{variants}')
    return str(path)


def variant(name: str, config: str, extra: str = "") -> str:
    return f'[[variant]]\nname = "{name}"\nconfig = "{config}"\n{extra}\n'


def by_label(result) -> dict:
    return {row.label: row for row in result.rows}


def test_an_unmasked_random_start_leaves_floaters(scene, tmp_path):
    study = load_study(write_study(scene, "unmasked", '[sessions.clean]\npath = "scene.zarr"\n',
                                   variant("hull", "hull.toml") + variant("unmasked", "unmasked.toml")))
    result = run_stability(study, tmp_path / "out", seeds=2, workers=0, progress=False)
    rows = by_label(result)
    assert [(row.label, row.runs) for row in result.rows] == [("hull", 2), ("unmasked", 2)]
    assert rows["hull"].unstable == 0.0 and rows["hull"].floater_share_mean < FLOATER_THRESHOLD / 2
    assert rows["unmasked"].fractions["floaters"] == 1.0 and rows["unmasked"].floater_share_mean > 5 * FLOATER_THRESHOLD
    assert rows["unmasked"].fractions["diverged"] == rows["unmasked"].fractions["failed"] == 0.0
    report = (tmp_path / "out" / "stability.md").read_text()
    assert "| unmasked | 2 | 0% | 0% | 100% | 0% | 0% | 0% | 0% | 100% |" in report and "| hull | 2 | 0% | 0% | 0% | 0% | 0% | 0% | 0% | 0% |" in report
    assert report.count("**floaters**") == 2


def test_three_training_cameras_are_reported(scene, tmp_path):
    sessions = ('[sessions.clean]\npath = "scene.zarr"\n'
                '[sessions.three]\npath = "scene.zarr"\ncameras = ["cam_0", "cam_1", "cam_2", "cam_3"]\n')
    study = load_study(write_study(scene, "cameras", sessions, variant("hull", "hull.toml")))
    result = run_stability(study, tmp_path / "out", seeds=1, workers=0, progress=False)
    assert [row.label for row in result.rows] == ["hull @ clean", "hull @ three"]
    clean, three = result.verdicts
    assert clean.classes == () and three.classes == ("warned",)
    assert "only 3 training cameras see the subject" in three.reasons[0]
    # The cell trained on three, from a copy of the session that keeps four; the original is untouched.
    row = result.run.rows[1]
    assert len(json.loads((tmp_path / "out" / "cells" / row.cell.spec.key / "run.json").read_text())["train_cameras"]) == 3
    assert SessionReader(row.cell.plan.url).camera_names == ("cam_0", "cam_1", "cam_2", "cam_3")
    assert SessionReader(scene / "scene.zarr").camera_names == tuple(f"cam_{i}" for i in range(5))
    assert "**warned**: only 3 training cameras see the subject" in (tmp_path / "out" / "stability.md").read_text()


def test_a_camera_with_wrong_extrinsics_is_detected_and_named(tmp_path):
    # The synthetic capture's eight cameras; in one copy cam_1 is turned 10° (its mask then lies half
    # off the other cameras' visual hull: 54 % on it, measured), in the other nothing is changed.
    capture = 'synthetic = { frames = 1, cameras = 8, width = 64, height = 48, samples = 1 }\n'
    sessions = (f'[sessions.clean]\n{capture}[sessions.wrong]\n{capture}perturb = {{ camera = "cam_1", degrees = 10 }}\n')
    variants = variant("hull", "visual-hull", 'set = { fit.iterations = 2, "initializer.visual-hull.num_points" = 100 }\n'
                                              'renderer = { name = "torch-reference" }')
    study = load_study(write_study(tmp_path, "wrong", sessions, variants))
    result = run_stability(study, tmp_path / "out", seeds=1, workers=0, progress=False)
    clean, wrong = (row.outcome for row in result.run.rows)
    assert min(clean.mask_agreement.values()) > 0.99 and "calibration" not in classify(clean).classes
    assert min(wrong.mask_agreement, key=wrong.mask_agreement.get) == "cam_1" and wrong.mask_agreement["cam_1"] < AGREEMENT_THRESHOLD - 0.15
    assert sorted(name for name, score in wrong.mask_agreement.items() if score < AGREEMENT_THRESHOLD) == ["cam_1"]
    verdict = result.verdicts[1]
    assert "calibration" in verdict.classes and "'cam_1'" in verdict.reasons[verdict.classes.index("calibration")]
    # Only the perturbed camera's extrinsics differ in the study's copy.
    original = SessionReader(next(row.cell.plan.url for row in result.run.rows if row.cell.session == "clean"))
    copy = SessionReader(next(row.cell.plan.url for row in result.run.rows if row.cell.session == "wrong"))
    assert not (copy.camera("cam_1").R == original.camera("cam_1").R).all() and (copy.camera("cam_2").R == original.camera("cam_2").R).all()
    record = json.loads((tmp_path / "out" / "stability.json").read_text())
    assert record["thresholds"]["mask_agreement"] == AGREEMENT_THRESHOLD and record["cells"][1]["mask_agreement"]["cam_1"] < AGREEMENT_THRESHOLD


def test_a_subject_leaving_the_view_is_flagged_without_a_crash(tmp_path):
    # The infant slides 1.5 m/s along +x; at 2 fps frame 2 is a second and a half later, out of some views.
    sessions = ('[sessions.leaving]\nsynthetic = { frames = 3, fps = 2.0, slide = 1.5, cameras = 5, width = 32, height = 24, '
                'samples = 1, adult_leg = false }\nfolds = ["cam_1"]\n')
    variants = variant("at-0", "visual-hull", 'set = { fit.iterations = 2, "initializer.visual-hull.num_points" = 100 }\nrenderer = { name = "torch-reference" }')
    variants += variant("at-2", "visual-hull", 'set = { fit.iterations = 2, fit.frame = 2, "initializer.visual-hull.num_points" = 100 }\n'
                        'renderer = { name = "torch-reference" }')
    study = load_study(write_study(tmp_path, "leaving", sessions, variants))
    result = run_stability(study, tmp_path / "out", seeds=1, workers=0, progress=False)
    rows = by_label(result)
    assert rows["at-0"].unstable == 0.0, result.verdicts
    left = [verdict for row, verdict in zip(result.run.rows, result.verdicts) if row.cell.variant == "at-2"]
    # Two of its four training cameras lose the subject: the fit warns, and floaters are left where it was.
    assert "warned" in left[0].classes and "only 2 training cameras see the subject at frame 2" in left[0].reasons[left[0].classes.index("warned")]
    assert set(left[0].classes) <= {"warned", "floaters"}
    assert "at-2" in (tmp_path / "out" / "stability.md").read_text().split("## Flagged runs")[1]


def test_a_loss_blowing_up_is_detected(scene, tmp_path):
    # A camera colour learning rate of 1000 scales the training renders far out of range: the loss stays
    # finite but its block means go from 0.29 to over 1000 within 8 iterations (measured).
    variants = variant("blowing", "hull.toml", 'set = { fit.iterations = 8, "fit.lrs.camera_color" = 1e3 }')
    study = load_study(write_study(scene, "blowing", '[sessions.clean]\npath = "scene.zarr"\n', variants))
    result = run_stability(study, tmp_path / "out", seeds=2, workers=0, progress=False)
    assert [row.outcome.status for row in result.run.rows] == ["complete", "complete"]
    for row, verdict in zip(result.run.rows, result.verdicts):
        assert row.outcome.loss_final > 100 * row.outcome.loss_min
        assert verdict.classes[0] == "diverged" and verdict.reasons[0].startswith("loss blew up")
    assert result.rows[0].fractions["diverged"] == 1.0


def test_a_diverging_variant_is_recorded_and_the_fractions_are_right(scene, tmp_path, capsys):
    # An absurd scale learning rate drives the parameters to Inf within a few iterations.
    variants = variant("fine", "short.toml") + variant("absurd", "short.toml", 'set = { "fit.lrs.log_scales" = 1e30 }')
    path = write_study(scene, "diverging", '[sessions.clean]\npath = "scene.zarr"\n', variants)
    assert main(["stability", path, "--out", str(tmp_path / "out"), "--workers", "0", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "| fine | 5 | 0% | 0% |" in printed and "| absurd | 5 | 100% | 0% |" in printed and "5 seeds" in printed
    record = json.loads((tmp_path / "out" / "stability.json").read_text())
    assert record["seeds"] == [0, 1, 2, 3, 4]
    absurd = [cell for cell in record["cells"] if cell["variant"] == "absurd"]
    assert len(absurd) == 5 and all(cell["status"] == "diverged" and "non-finite" in cell["error"] for cell in absurd)
    variants_by_name = {row["variant"]: row for row in record["variants"]}
    assert variants_by_name["absurd"]["diverged"] == 1.0 and variants_by_name["absurd"]["val_masked_psnr_mean"] is None
    assert variants_by_name["fine"]["diverged"] == 0.0 and variants_by_name["fine"]["runs"] == 5
    assert variants_by_name["fine"]["val_masked_psnr_min"] <= variants_by_name["fine"]["val_masked_psnr_mean"]
    csv = (tmp_path / "out" / "stability.csv").read_text().splitlines()
    assert csv[0].startswith("label,variant,session,backend,runs,diverged,failed,floaters,calibration,overfit,drift,warned,unstable") and len(csv) == 3
    # compare over the same directory reuses the cells and lists the diverged ones.
    results = (tmp_path / "out" / "results.md").read_text()
    assert results.count(", diverged: NonFiniteError") == 5


def test_classification_of_single_cells():
    good = CellOutcome("k", "complete", val_masked_psnr=20.0, floater_share=0.02, loss_min=0.1, loss_final=0.12, warnings=[])
    assert classify(good).classes == ()
    assert classify(CellOutcome("k", "complete", val_masked_psnr=float("nan"))).classes == ("diverged",)
    blown = classify(CellOutcome("k", "complete", val_masked_psnr=9.0, loss_min=0.1, loss_final=0.1 * BLOWUP_FACTOR * 1.01))
    assert blown.classes == ("diverged",) and "blew up" in blown.reasons[0]
    assert classify(CellOutcome("k", "complete", loss_min=0.1, loss_final=0.1 * BLOWUP_FACTOR)).classes == ()
    assert classify(CellOutcome("k", "complete", floater_share=FLOATER_THRESHOLD + 0.01, drift=True, warnings=["camera 'cam_3' never sees the subject"])).classes \
        == ("floaters", "drift", "warned")
    off = classify(CellOutcome("k", "complete", mask_agreement={"cam_1": 1.0, "cam_2": AGREEMENT_THRESHOLD - 0.01, "cam_3": 0.3}))
    assert off.classes == ("calibration",) and off.reasons[0].index("'cam_3'") < off.reasons[0].index("'cam_2'") and "cam_1" not in off.reasons[0]
    assert classify(CellOutcome("k", "complete", mask_agreement={"cam_1": AGREEMENT_THRESHOLD})).classes == ()
    assert classify(CellOutcome("k", "complete", train_masked_psnr=20.0, val_masked_psnr=20.0 - GAP_DB - 0.1)).classes == ("overfit",)
    assert classify(CellOutcome("k", "complete", train_masked_psnr=20.0, val_masked_psnr=20.0 - GAP_DB)).classes == ()
    assert classify(CellOutcome("k", "failed", "ValueError: x")).classes == ("failed",)
    assert classify(CellOutcome("k", "diverged", "NonFiniteError: y")).reasons == ("NonFiniteError: y",)


@pytest.mark.parametrize("table, message", [
    ('cameras = ["cam_0", "cam_9"]', r"\[sessions.s\] cameras: no camera 'cam_9' in the session"),
    ('perturb = { camera = "cam_4", degrees = 5 }\ncameras = ["cam_0", "cam_1", "cam_2"]',
     r"\[sessions.s\] perturb: no camera 'cam_4' in the session as its 'cameras' keep it"),
])
def test_session_modifications_name_what_is_wrong(scene, tmp_path, table, message):
    with pytest.raises(StudyError, match=message):  # when the study loads: before, after its other sessions were made
        load_study(write_study(scene, "bad", f'[sessions.s]\npath = "scene.zarr"\n{table}\n', variant("a", "short.toml")))


def test_a_malformed_perturbation_is_refused(scene):
    with pytest.raises(StudyError, match="perturb must be a table"):
        load_study(write_study(scene, "bad2", '[sessions.s]\npath = "scene.zarr"\nperturb = { camera = "cam_1" }\n', variant("a", "short.toml")))
