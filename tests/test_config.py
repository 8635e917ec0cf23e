"""Configurations: loading, plugin selection, overrides, clear errors."""

from __future__ import annotations

import pytest

from mmcsplat.configuration.config import ConfigError, apply_override, load_config, set_value


def write(tmp_path, text: str):
    path = tmp_path / "run.toml"
    path.write_text(text)
    return path


def test_plugin_choices_and_params(tmp_path):
    config = load_config(write(tmp_path, '[renderer]\nname = "torch-reference"\n[[initializer]]\nname = "a"\nn = 3\n[[initializer]]\nname = "b"\n'))
    assert config.plugin("renderer").name == "torch-reference"
    assert [(c.name, dict(c.params)) for c in config.plugins("initializer")] == [("a", {"n": 3}), ("b", {})]
    assert config.plugins("dynamics") == []
    with pytest.raises(ConfigError, match="exactly one"):
        config.plugin("initializer")


def test_selected_plugin_builds_through_registry(tmp_path):
    metric = load_config(write(tmp_path, '[metric]\nname = "psnr"\n')).plugin("metric").build()
    import numpy as np

    assert metric(np.zeros((2, 2, 3)), np.full((2, 2, 3), 0.1)) == pytest.approx(20.0)


def test_overrides_parse_values(tmp_path):
    config = load_config(write(tmp_path, "[fit]\niterations = 10\n"), ["fit.iterations=20", "renderer.name=fast", "fit.lrs=[1, 2]"])
    assert config.get("fit.iterations") == 20
    assert config.get("renderer.name") == "fast"
    assert config.get("fit.lrs") == [1, 2]
    assert config.get("fit.missing", "d") == "d"
    with pytest.raises(ConfigError, match="key.path=value"):
        apply_override({}, "no-equals-sign")
    with pytest.raises(ConfigError, match="not a table"):
        apply_override({"train": 1}, "train.x=1")


def test_overrides_reach_into_arrays_of_tables_by_index_or_name():
    values = {"initializer": [{"name": "random", "num_points": 10}, {"name": "masked"}]}
    assert set_value(values, "initializer.random.num_points", 5)["initializer"][0]["num_points"] == 5
    assert apply_override(values, "initializer.1.radius=2.5")["initializer"][1] == {"name": "masked", "radius": 2.5}
    assert values["initializer"][0]["num_points"] == 10  # a copy, the original untouched
    with pytest.raises(ConfigError, match="no table named 'visual-hull'"):
        set_value(values, "initializer.visual-hull.num_points", 5)
    with pytest.raises(ConfigError, match="index 2 is past the 2 table"):
        set_value(values, "initializer.2.num_points", 5)


def test_an_unknown_table_is_refused_not_ignored(tmp_path):
    for source, overrides in [("[fitt]\niterations = 3\n", []), ("[fit]\n", ["nosection.x=3"])]:
        with pytest.raises(ConfigError, match="unknown table.*a configuration has fit, renderer"):
            load_config(write(tmp_path, source), overrides)


def test_errors_name_the_source(tmp_path):
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(write(tmp_path, "[renderer\n"))
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="unknown configuration 'no-such-config'"):
        load_config("no-such-config")
    with pytest.raises(ConfigError, match=r"\[renderer\] must be a table"):
        load_config(write(tmp_path, "[renderer]\nnot_name = 1\n")).plugins("renderer")
