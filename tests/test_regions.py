"""Start and pruning regions grown to hold the subject's visual hull before a fit (never shrunk), and the
fit's refusal when the user keeps regions too small for the subject."""

from __future__ import annotations

import numpy as np
import pytest
from fitting_scene import write_config, write_session

from mmcsplat.cli.main import main
from mmcsplat.configuration.config import load_config
from mmcsplat.pipeline.regions import hull_offsets, region_overrides
from mmcsplat.storage.session import SessionReader


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("regions") / "s.zarr", frames=1)


def test_regions_grow_to_hold_the_subjects_hull_and_are_never_shrunk(session, tmp_path):
    reader = SessionReader(session)
    offsets = hull_offsets(reader, None, 0)
    cube, sphere = np.abs(offsets).max(), np.linalg.norm(offsets, axis=1).max()
    assert 0.05 < cube < 0.4  # the test scene's subject is a 24 cm cloud, its 4-view hull a little larger
    config = write_config(tmp_path / "fit.toml")  # a 0.25 m start cube and 2 m pruning sphere hold it
    assert region_overrides(reader, load_config(config)) == []
    assert region_overrides(reader, load_config(config, ["initializer.0.half_size=5"])) == []  # never shrunk
    small = load_config(config, ["initializer.0.half_size=0.05", "initializer.1.radius=0.05"])
    assert region_overrides(reader, small) == [f"initializer.0.half_size={np.ceil((cube + 0.1) * 10) / 10}",
                                               f"initializer.1.radius={np.ceil((sphere + 0.1) * 10) / 10}"]


def test_fit_grows_a_small_region_and_refuses_it_with_fixed_regions(session, tmp_path, capsys):
    config = str(write_config(tmp_path / "fit.toml", iterations=3))
    small = ["--set", "initializer.0.half_size=0.05"]
    assert main(["fit", str(session), "--config", config, "--out", str(tmp_path / "fixed"), "--fixed-regions", "--no-progress", *small]) == 2
    assert "only" in capsys.readouterr().err and not (tmp_path / "fixed" / "run.json").exists()
    assert main(["fit", str(session), "--config", config, "--out", str(tmp_path / "grown"), "--no-progress", *small]) == 0
    assert "regions grown to hold the subject's visual hull: initializer.0.half_size=0." in capsys.readouterr().out
