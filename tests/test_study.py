"""Studies: the file format and its errors, grid expansion, cell keys, running (process pool, in-process,
Ray), resuming an interrupted study, and the tables and charts it writes."""

from __future__ import annotations

import json
import re
import sys

import attrs
import numpy as np
import pytest
from fitting_scene import moved, subject, write_config, write_ground_truth, write_session

from mmcsplat.cli import main
from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.fit import CHECKPOINT, FirstFrameFit
from mmcsplat.storage.session import SessionReader
from mmcsplat.studies.cells import RESULT_FILE, CellOutcome
from mmcsplat.studies.results import derive_columns, pareto_front
from mmcsplat.studies.runner import publish, run_study
from mmcsplat.studies.sessions import prepare_session
from mmcsplat.studies.spec import StudyError, cell_key, expand, load_study


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A folder with the fitting scene's session and a two-iteration configuration."""
    folder = tmp_path_factory.mktemp("study")
    write_session(folder / "scene.zarr")
    write_config(folder / "fit.toml", iterations=2, checkpoint_every=1)
    return folder


def write_study(folder, body: str, name: str = "study.toml", session: str = 'path = "scene.zarr"'):
    path = folder / name
    path.write_text(f'[study]\nname = "tiny"\n{body.strip()}\n\n[sessions.scene]\n{session}\n')
    return path


def variant(name: str, extra: str = "") -> str:
    return f'\n[[variant]]\nname = "{name}"\nconfig = "fit.toml"\n{extra}\n'


def test_grid_and_rows_expand_into_cells(scene, tmp_path):
    study = load_study(write_study(scene, 'folds = ["cam_0", "cam_2"]\nseeds = [0, 1]\nset = { "fit.lambda_seg" = 1.0 }\n'
                                   + variant("base")
                                   + variant("grid", 'grid = { initializer.random.num_points = [50, 100], "fit.lambda_seg" = [0.0, 2.0] }')
                                   + variant("row", 'set = { "initializer.0.half_size" = 0.3 }\ndensifier = { name = "budget", cap = 300 }')))
    names = [v.name for v in study.variants]
    assert names == ["base", "grid (num_points=50, lambda_seg=0.0)", "grid (num_points=50, lambda_seg=2.0)",
                     "grid (num_points=100, lambda_seg=0.0)", "grid (num_points=100, lambda_seg=2.0)", "row"]
    by_name = {v.name: v.config for v in study.variants}
    assert by_name["base"].get("fit.lambda_seg") == 1.0  # the study-wide override
    assert by_name["grid (num_points=100, lambda_seg=0.0)"].get("fit.lambda_seg") == 0.0  # the grid wins over it
    assert by_name["grid (num_points=100, lambda_seg=0.0)"].values["initializer"][0]["num_points"] == 100
    assert by_name["row"].values["initializer"][0]["half_size"] == 0.3
    assert by_name["row"].values["densifier"] == {"name": "budget", "cap": 300}  # replaced whole
    cells = expand(study, tmp_path)
    assert len(cells) == 6 * 2 * 2  # variants × folds × seeds
    assert {(c.fold, c.seed) for c in cells} == {("cam_0", 0), ("cam_0", 1), ("cam_2", 0), ("cam_2", 1)}
    assert all(c.spec.config_values["fit"]["seed"] == c.seed for c in cells)
    assert len({c.spec.key for c in cells}) == len(cells)


def test_cell_keys_are_stable_and_cover_what_decides_a_result(scene, tmp_path):
    config = {"fit": {"iterations": 2, "seed": 0}, "renderer": {"name": "torch-cpu"}}
    # Pinned: a change of this value makes every existing study directory run again.
    assert cell_key(config, {"path": "/s.zarr"}, ["cam_0"], 0, "torch-cpu") == "4904fab2d7c88ad6"
    reordered = {"renderer": {"name": "torch-cpu"}, "fit": {"seed": 0, "iterations": 2}}
    assert cell_key(reordered, {"path": "/s.zarr"}, ("cam_0",), 0, "torch-cpu") == "4904fab2d7c88ad6"
    for changed in [({**config, "fit": {"iterations": 3, "seed": 0}}, {"path": "/s.zarr"}, ["cam_0"], 0, "torch-cpu"),
                    (config, {"path": "/t.zarr"}, ["cam_0"], 0, "torch-cpu"), (config, {"path": "/s.zarr"}, ["cam_1"], 0, "torch-cpu"),
                    (config, {"path": "/s.zarr"}, ["cam_0"], 1, "torch-cpu"), (config, {"path": "/s.zarr"}, ["cam_0"], 0, "jax")]:
        assert cell_key(*changed) != "4904fab2d7c88ad6"
    # The same study read twice gives the same keys; renaming a variant does not change its cells.
    body = 'folds = ["cam_0"]\n' + variant("a")
    first = [c.spec.key for c in expand(load_study(write_study(scene, body, "one.toml")), tmp_path)]
    again = [c.spec.key for c in expand(load_study(write_study(scene, body.replace('"a"', '"renamed"'), "two.toml")), tmp_path)]
    assert first == again


BAD_STUDIES = [
    ("[study\n", "invalid TOML"),
    ('[study]\nname = "x"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n', r"\[sessions\] is missing"),
    ('[study]\n[sessions.s]\npath = "s.zarr"\n[[variants]]\nname = "a"\n', r"unknown top-level key\(s\) \['variants'\]"),
    ('[sessions.s]\npath = "s.zarr"\nsynthetic = {}\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n', "exactly one of 'path'"),
    ('[sessions.s]\nsynthetic = { legs = 3 }\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n', r"\[sessions.s\] synthetic: .*legs"),
    ('[sessions.s]\npath = "s.zarr"\n', r"no \[\[variant\]\] table"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\n', "variant 'a' needs 'config'"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "no-such-config"\n', "unknown configuration 'no-such-config'"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\ngrid = { "fit.lambda_seg" = 1 }\n', "non-empty list"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\ninitializer = [{ name = "rando" }]\n',
     "variant 'a': unknown initializer 'rando'"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\nset = { "fit.iteration" = 5 }\n', r"\[fit\]: unknown parameter\(s\) iteration; known: iterations"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\nset = { "fitt.iterations" = 5 }\n', r"unknown table\(s\) 'fitt'"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\nset = { "initializer.rando.x" = 5 }\n', "no table named 'rando'"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n', "must be unique"),
    ('[study]\nseeds = [0.5]\n[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n', "list of integers"),
    ('[study]\nbackends = ["no-such-renderer"]\n[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n',
     "unknown renderer 'no-such-renderer'"),
    # A misspelt parameter of a variant's plugin, in its table or its set, before anything runs (each cell failed on it).
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\ndensifier = { name = "budget", capp = 3 }\n',
     r"variant 'a': densifier 'budget': unknown parameter\(s\) capp; known: cap"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "visual-hull"\nset = { "initializer.visual-hull.num_pointz" = 3 }\n',
     r"variant 'a': initializer 'visual-hull': unknown parameter\(s\) num_pointz"),
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\ndynamics = { name = "iterative", iterationz = 3 }\n',
     r"bad.toml: variant 'a': dynamics 'iterative': unknown parameter\(s\) iterationz"),
    ('[sessions.s]\npath = "s.zarr"\nsegmenter = { name = "background", methd = "median" }\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n',
     r"segmenter 'background': unknown parameter\(s\) methd"),
    # A stored session that is not there: refused when the study loads, not kept as every cell's failure.
    ('[sessions.s]\npath = "s.zarr"\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n', r"\[sessions.s\] path: no session at .*s.zarr"),
]


@pytest.mark.parametrize("text, message", BAD_STUDIES)
def test_bad_study_files_name_what_is_wrong(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(StudyError, match=message):
        load_study(path)


def test_missing_and_unknown_studies(tmp_path, capsys):
    with pytest.raises(StudyError, match="does not exist"):
        load_study(tmp_path / "nope.toml")
    assert main(["compare", "no-such-study", "--out", str(tmp_path / "out")]) == 2
    assert "built-in ones are dynamics, paper-ablation" in capsys.readouterr().err


def test_unknown_fold_camera_fails_before_any_cell_runs(scene, tmp_path, capsys):
    with pytest.raises(StudyError, match=r"\[sessions.\w+\] folds: no camera 'cam_9' in the session; its cameras: \['cam_0'"):
        load_study(write_study(scene, 'folds = ["cam_9"]\n' + variant("a"), "fold.toml"))
    # A synthetic session's cameras are known before it is made: --dry-run listed such a cell as "to run".
    synthetic = tmp_path / "synthetic.toml"
    for table, message in (('folds = ["cam_4"]', r"folds: no camera 'cam_4' in the session; its cameras: \['cam_0', 'cam_1', 'cam_2', 'cam_3'\]"),
                           ('heldout = ["cam_4"]', "heldout: no camera 'cam_4'"),
                           ('cameras = ["cam_0", "cam_1"]\nfolds = ["cam_2"]', "folds: no camera 'cam_2' in the session as its 'cameras' keep it")):
        synthetic.write_text(f'[sessions.s]\nsynthetic = {{ cameras = 4 }}\n{table}\n[[variant]]\nname = "a"\nconfig = "paper-masked"\n')
        assert main(["compare", str(synthetic), "--out", str(tmp_path / "out"), "--dry-run"]) == 2
        assert re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def test_builtin_paper_ablation_has_the_studys_five_rows_then_its_own(tmp_path):
    study = load_study("paper-ablation")
    cells = expand(study, tmp_path)
    assert len(cells) == 11 * 4 and {c.fold for c in cells} == {"cam_0", "cam_2", "cam_4", "cam_6"}
    registry = default_registry()
    rows = [(c.mask, c.lambda_seg, c.sparse, c.init_points, c.init_range_m)
            for c in (derive_columns(variant.config, registry) for variant in study.variants)]
    assert rows[:5] == [(True, 3.0, False, 10_000, 1.5), (True, 3.0, False, 20_000, 1.5), (False, 3.0, False, 100_000, 10.0),
                        (False, 0.0, False, 100_000, 10.0), (True, 3.0, True, 10_000, 1.5)]
    assert [variant.name for variant in study.variants[5:]] == ["visual-hull", "masked-plate", "masked-sparse-seg0.3", "masked-plate-seg3",
                                                                "visual-hull-plate", "masked-plate-supersampled"]
    assert rows[6] == (True, 0.3, True, 10_000, 1.5) and rows[7][1] == 0.3 and rows[8][1] == 3.0
    assert study.sessions[0].synthetic["frames"] == 1 and study.sessions[0].segmenter.name == "precomputed"


def test_builtin_dynamics_study_compares_two_methods():
    registry = default_registry()
    if "deformation" not in registry.names("dynamics"):
        pytest.skip("the deformation dynamics method is not registered yet")
    study = load_study("dynamics")
    assert [v.config.plugin("dynamics").name for v in study.variants] == ["iterative", "deformation"]


def test_pareto_front():
    # (wall time, PSNR): the third is slower and worse than the second.
    assert pareto_front([(1.0, 10.0), (2.0, 12.0), (3.0, 11.0), (4.0, 13.0)], minimize_x=True) == [0, 1, 3]
    assert pareto_front([(1.0, 10.0), (2.0, 12.0), (3.0, 11.0)], minimize_x=False) == [1, 2]


def test_study_runs_in_a_process_pool_writes_results_and_reuses_done_cells(scene, tmp_path, capsys):
    study = write_study(scene, 'folds = ["cam_0", "cam_2"]\n' + variant("small", 'set = { "initializer.random.num_points" = 40 }')
                        + variant("large"), "pool.toml")
    out = tmp_path / "out"
    assert main(["compare", str(study), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert "4 cells, 4 run now, 0 reused" in capsys.readouterr().out
    for name in ("results.csv", "results.json", "results.md", "study.toml", "charts/speed_accuracy.png", "charts/speed_accuracy.svg",
                 "charts/psnr_gaussians.png", "charts/psnr_gaussians.svg"):
        assert (out / name).stat().st_size > 0, name
    results = json.loads((out / "results.json").read_text())
    assert len(results["cells"]) == 4 and all(cell["status"] == "complete" for cell in results["cells"])
    small = next(v for v in results["variants"] if v["variant"] == "small")
    assert small["cells"] == 2 and small["init_points"] == 40 and small["mask"] is True and small["val_masked_psnr_std"] is not None
    assert small["iterations"] == 2 and small["iterations_per_s"] > 0 and small["num_gaussians"] <= 40
    assert results["findings"]["smallest_within"] in {"small", "large"}
    table = (out / "results.md").read_text()
    assert "| Mask | λ_seg | Sparse | #init points | init range (m) | val PSNR | train PSNR |" in table
    assert "| small | yes | 3 | no | 40 | 0.5 |" in table and "charts/speed_accuracy.png" in table
    assert len((out / "results.csv").read_text().splitlines()) == 1 + 4 + 2  # header, cells, variants

    done = {path: path.stat().st_mtime_ns for path in out.glob("cells/*/result.json")}
    again = run_study(load_study(study), out, progress=False)
    assert (again.ran, again.reused) == (0, 4)
    assert {path: path.stat().st_mtime_ns for path in out.glob("cells/*/result.json")} == done

    page = tmp_path / "docs" / "results.md"
    page.parent.mkdir()
    page.write_text("# Results\n\nHand-written introduction.\n")
    for _ in range(2):  # the second replaces the first's section
        publish(again, page, "mmcsplat compare pool.toml --out out --publish docs/results.md")
    text = page.read_text()
    assert text.startswith("# Results\n\nHand-written introduction.") and text.count("<!-- study: tiny -->") == 1
    assert "![Speed against accuracy](results/tiny/speed_accuracy.png)" in text and "`mmcsplat compare pool.toml" in text
    assert (tmp_path / "docs" / "results" / "tiny" / "psnr_gaussians.svg").stat().st_size > 0


def test_interrupted_study_skips_done_cells_and_resumes_the_cut_off_fit(scene, tmp_path, monkeypatch):
    write_config(tmp_path / "fit.toml", iterations=3, checkpoint_every=1)
    study = load_study(write_study(tmp_path, 'folds = ["cam_0", "cam_2"]\n' + variant("a"),
                                   session=f'path = "{scene / "scene.zarr"}"'))
    original = FirstFrameFit._checkpoint

    def killed(self, path, *state):
        original(self, path, *state)
        if self.heldout_cameras[0].name == "cam_2" and state[-2] == 1:  # after the checkpoint at 1 iteration
            raise KeyboardInterrupt
    monkeypatch.setattr(FirstFrameFit, "_checkpoint", killed)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_study(study, out, workers=0, progress=False)
    first, second = (out / "cells" / cell.spec.key for cell in expand(study, out))
    assert (first / RESULT_FILE).exists() and not (second / RESULT_FILE).exists() and (second / CHECKPOINT).exists()
    finished_at = (first / RESULT_FILE).stat().st_mtime_ns

    monkeypatch.setattr(FirstFrameFit, "_checkpoint", original)
    result = run_study(study, out, workers=0, progress=False)
    assert (result.ran, result.reused) == (1, 1)
    assert (first / RESULT_FILE).stat().st_mtime_ns == finished_at
    outcome = next(row.outcome for row in result.rows if row.cell.fold == "cam_2")
    assert outcome.status == "complete" and outcome.resumed_at == 1 and outcome.iterations == 3


def test_a_dynamics_cell_tracks_and_charts_frame_by_frame(tmp_path):
    write_session(tmp_path / "moving.zarr", frames=3)
    write_ground_truth(tmp_path / "truth.zarr", frames=3)
    import zarr

    leg = np.stack([moved(subject(), t).means.numpy()[[0, 1, 2]] for t in range(3)])  # three of the subject's Gaussians as a leg's joints
    zarr.open_group(str(tmp_path / "truth.zarr"), mode="a").create_array(
        "joints", data=leg.astype(np.float32), attributes={"joint_names": ["hip_left", "knee_left", "ankle_left"]})
    write_config(tmp_path / "fit.toml", iterations=2, checkpoint_every=2)
    # Initial points in a cube that holds the subject's hull (the region check), dense enough that some sit within the
    # tracking evaluation's follow radius.
    study = load_study(write_study(tmp_path, 'folds = ["cam_0"]\n' + variant(
        "iterative", 'set = { "initializer.random" = { num_points = 8000, half_size = 0.45 } }\ndynamics = { name = "iterative", iterations = 1, neighbours = 4 }'),
        session='path = "moving.zarr"\nground_truth = "truth.zarr"'))
    result = run_study(study, tmp_path / "out", workers=0, progress=False)
    outcome = result.rows[0].outcome
    assert outcome.status == "complete", outcome.error
    assert outcome.track_method == "iterative" and outcome.tracking_median_mm is not None
    assert len(outcome.per_frame_val_masked_psnr) == 3 and len(outcome.tracking_per_frame_median_mm) == 3
    assert (tmp_path / "out" / "charts" / "dynamics.svg").stat().st_size > 0
    assert "## Dynamics" in (tmp_path / "out" / "results.md").read_text()
    # The joints carried by the tracks: their errors and the knee's range of motion (the only angle these three joints give).
    assert outcome.landmark_median_mm is not None and outcome.joint_angle_median_error_deg is not None
    assert outcome.knee_flexion_range_deg is not None and outcome.hip_flexion_range_deg is None
    aggregated = json.loads((tmp_path / "out" / "results.json").read_text())["variants"][0]
    assert aggregated["knee_flexion_range_deg"] == pytest.approx(outcome.knee_flexion_range_deg)
    assert "joint angles, median error (°)" in (tmp_path / "out" / "results.md").read_text()


def test_cells_differing_only_in_dynamics_share_one_fit(tmp_path):
    """Two tracking rows in two worker processes at once: one fit, made under the lock the other waits on and
    copied into both cells, each of whose run.json records its own dynamics; a row with another fit has its own."""
    write_session(tmp_path / "moving.zarr", frames=3)
    write_config(tmp_path / "fit.toml", iterations=2, checkpoint_every=2)
    start = 'set = { "initializer.random" = { num_points = 2000, half_size = 0.45 } }\n'
    study = load_study(write_study(tmp_path, 'folds = ["cam_0"]\n'
                                   + variant("one step", start + 'dynamics = { name = "iterative", iterations = 1, neighbours = 4 }')
                                   + variant("two steps", start + 'dynamics = { name = "iterative", iterations = 2, neighbours = 4 }')
                                   + variant("other fit", start.replace("2000", "1000") + 'dynamics = { name = "iterative", iterations = 1, neighbours = 4 }'),
                                   session='path = "moving.zarr"'))
    result = run_study(study, tmp_path / "out", workers=2, progress=False)
    assert all(row.outcome.status == "complete" for row in result.rows), [row.outcome.error for row in result.rows]
    cells = {row.cell.variant: tmp_path / "out" / "cells" / row.outcome.key for row in result.rows}
    fits = sorted(path.name for path in (tmp_path / "out" / "fits").iterdir() if path.is_dir())
    assert len(fits) == 2
    shared = json.loads((cells["one step"] / "cell.json").read_text())["fit"]
    assert shared == json.loads((cells["two steps"] / "cell.json").read_text())["fit"] != json.loads((cells["other fit"] / "cell.json").read_text())["fit"]
    assert (cells["one step"] / CHECKPOINT).read_bytes() == (cells["two steps"] / CHECKPOINT).read_bytes()
    runs = {name: json.loads((cell / "run.json").read_text()) for name, cell in cells.items()}
    assert runs["one step"]["wall_s"] == runs["two steps"]["wall_s"]  # the one fit's time, not two fits'
    assert [runs[name]["config_values"]["dynamics"]["iterations"] for name in ("one step", "two steps")] == [1, 2]
    assert "dynamics" not in json.loads((tmp_path / "out" / "fits" / fits[0] / "run.json").read_text())["config_values"]
    assert [json.loads((cell / "track.json").read_text())["params"]["iterations"] for cell in (cells["one step"], cells["two steps"])] == [1, 2]


def test_a_cell_recorded_before_the_movement_measures_still_reads(tmp_path):
    (tmp_path / RESULT_FILE).write_text(json.dumps({"key": "old", "status": "complete", "landmark_median_mm": 3.5}))
    outcome = CellOutcome.read(tmp_path)  # still done: not run again for the fields added since
    assert outcome.landmark_median_mm == 3.5 and outcome.knee_flexion_range_deg is None


def test_a_synthetic_session_is_synthesized_ingested_and_segmented_once(tmp_path):
    study = load_study(write_study(tmp_path, 'folds = ["cam_1"]\nset = { fit.iterations = 1, "initializer.random.num_points" = 200 }\n'
                                   '[[variant]]\nname = "masked"\nconfig = "paper-masked"\nrenderer = { name = "torch-reference" }',
                                   session="synthetic = { frames = 1, cameras = 4, width = 32, height = 24, samples = 1, adult_leg = false }"))
    result = run_study(study, tmp_path / "out", workers=0, progress=False)
    assert result.rows[0].outcome.status == "complete", result.rows[0].outcome.error
    plan = result.rows[0].cell.plan
    assert plan.identity["synthetic"]["cameras"] == 4 and plan.identity["segmenter"]["name"] == "precomputed"
    assert SessionReader(plan.url).has("mask") and plan.url.startswith(str(tmp_path / "out" / "sessions" / "scene"))
    capture = tmp_path / "out" / "sessions" / "scene" / "capture" / "calibration.toml"
    made = capture.stat().st_mtime_ns
    prepare_session(plan, progress=False)  # ready: nothing is made again
    assert capture.stat().st_mtime_ns == made
    other = attrs.evolve(plan.spec, synthetic={**plan.spec.synthetic, "cameras": 5})
    changed = attrs.evolve(plan, spec=other, url=plan.url.replace(".zarr", "-other.zarr"), identity={**plan.identity, "synthetic": other.synthetic})
    with pytest.raises(StudyError, match="synthesized with other settings"):
        prepare_session(changed, progress=False)


def test_the_ray_executor_without_ray_is_a_clear_error(scene, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed
    study = load_study(write_study(scene, 'folds = ["cam_0"]\n' + variant("a"), "noray.toml"))
    with pytest.raises(StudyError, match=r"needs Ray, which is not installed here: pip install 'mmcsplat\[distributed\]'"):
        run_study(study, tmp_path / "out", executor="ray", progress=False)
    assert not list((tmp_path / "out").glob("cells/*"))


def test_study_runs_as_ray_tasks(scene, tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'mmcsplat[distributed]')")
    study = load_study(write_study(scene, 'folds = ["cam_0"]\nseeds = [3]\n' + variant("a"), "ray.toml"))
    ray.init(num_cpus=1, include_dashboard=False)
    try:
        result = run_study(study, tmp_path / "out", executor="ray", progress=False)
    finally:
        ray.shutdown()
    assert [row.outcome.status for row in result.rows] == ["complete"]
    assert (tmp_path / "out" / "results.md").stat().st_size > 0
