"""Start and pruning regions grown by their initializers to hold the subject's visual hull before a fit
(never shrunk), recorded in run.json, and the fit's refusal when the user keeps regions too small."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fitting_scene import write_config, write_session

from mmcsplat.cli.main import main
from mmcsplat.configuration.config import load_config
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.scene.rig import rig_center, rig_scale
from mmcsplat.scene.visual_hull import hull_cells
from mmcsplat.storage.session import SessionReader


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("regions") / "s.zarr", frames=1)


def fit_of(session, config, out, **options) -> FirstFrameFit:
    """A fit set up (not run): its initializers have chosen their regions."""
    return FirstFrameFit(SessionReader(session), config, out, progress=False, **options)


def test_the_scene_gives_the_hull_of_the_training_masks_once(session, tmp_path):
    reader = SessionReader(session)
    scene = fit_of(session, load_config(write_config(tmp_path / "fit.toml")), tmp_path / "run").scene
    center = rig_center(reader.cameras)
    views = [(camera, reader.frame(0, camera.name).mask) for camera in scene.cameras]
    offsets = hull_cells(views, center, rig_scale(reader.cameras, center)) - center
    np.testing.assert_allclose(scene.subject_reach(cube=True), np.abs(offsets).max(axis=1))
    np.testing.assert_allclose(scene.subject_reach(cube=False), np.linalg.norm(offsets, axis=1))
    assert 0.05 < np.abs(offsets).max() < 0.4  # the test scene's subject is a 24 cm cloud, its 4-view hull a little larger


def test_regions_grow_to_hold_the_subjects_hull_and_are_never_shrunk(session, tmp_path):
    config = write_config(tmp_path / "fit.toml")  # a 0.25 m start cube and 2 m pruning sphere hold it
    held = fit_of(session, load_config(config), tmp_path / "held")
    assert held.grown_regions == [] and held.config == load_config(config)
    large = fit_of(session, load_config(config, ["initializer.0.half_size=5"]), tmp_path / "large")
    assert large.grown_regions == [] and large.initializers[0].half_size == 5.0  # never shrunk
    small = fit_of(session, load_config(config, ["initializer.0.half_size=0.05", "initializer.1.radius=0.05"]), tmp_path / "small")
    cube, sphere = small.scene.subject_reach(cube=True).max(), small.scene.subject_reach(cube=False).max()
    grown_cube, grown_sphere = np.ceil((cube + 0.1) * 10) / 10, np.ceil((sphere + 0.1) * 10) / 10
    # The initializers the fit trains with, and the configuration it records, hold the grown sizes.
    assert (small.initializers[0].half_size, small.initializers[1].radius) == (grown_cube, grown_sphere)
    tables = small.config.values["initializer"]
    assert (tables[0]["half_size"], tables[1]["radius"], tables[0]["num_points"]) == (grown_cube, grown_sphere, 200)
    assert small.grown_regions == [
        f"initializer 'random': start cube's half side grown from 0.05 m to {grown_cube:g} m (half_size) to hold the subject's visual hull, "
        f"which reaches {cube:.2f} m from the rig centre",
        f"initializer 'masked': pruning sphere's radius grown from 0.05 m to {grown_sphere:g} m (radius) to hold the subject's visual hull, "
        f"which reaches {sphere:.2f} m from the rig centre"]
    assert small.warnings[-2:] == small.grown_regions
    kept = fit_of(session, load_config(config, ["initializer.0.half_size=0.05"]), tmp_path / "kept", grow_regions=False)
    assert kept.grown_regions == [] and kept.initializers[0].half_size == 0.05


def test_fit_grows_a_small_region_and_refuses_it_with_fixed_regions(session, tmp_path, capsys):
    config = str(write_config(tmp_path / "fit.toml", iterations=3))
    small = ["--set", "initializer.0.half_size=0.05"]
    assert main(["fit", str(session), "--config", config, "--out", str(tmp_path / "fixed"), "--fixed-regions", "--no-progress", *small]) == 2
    assert "only" in capsys.readouterr().err and not (tmp_path / "fixed" / "run.json").exists()
    assert main(["fit", str(session), "--config", config, "--out", str(tmp_path / "grown"), "--no-progress", *small]) == 0
    printed = capsys.readouterr().out
    assert "grown: initializer 'random': start cube's half side grown from 0.05 m to 0." in printed
    info = json.loads((tmp_path / "grown" / "run.json").read_text())
    assert 0.05 < info["config_values"]["initializer"][0]["half_size"] < 0.6
    assert any(warning.startswith("initializer 'random': start cube's half side grown") for warning in info["warnings"])
