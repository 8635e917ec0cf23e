"""The plugin registry: discovery through entry points, third-party plugins, clear errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import pytest

from mmcsplat import Registration, hookimpl
from mmcsplat.configuration.registry import (
    BrokenPluginError,
    DuplicatePluginError,
    PluginUnavailableError,
    Registry,
    UnknownPluginError,
    default_registry,
)
from mmcsplat.plugin_api.kinds import KIND_NAMES

THIRDPARTY = Path(__file__).parent / "thirdparty"


def run_python(code: str, *plugin_dirs: Path) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter with third-party plugin folders on its path."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([*map(str, plugin_dirs), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, env=env, timeout=120)


def run_cli(*args: str, plugin_dirs: tuple[Path, ...] = ()) -> subprocess.CompletedProcess:
    return run_python(f"import sys; from mmcsplat.cli import main; sys.exit(main({list(args)!r}))", *plugin_dirs)


def test_builtins_register_through_entry_points():
    registry = default_registry()
    entries = {(e.kind, e.name): e for e in registry.entries}
    for kind, name in [("renderer", "torch-reference"), ("reader", "videos"), ("metric", "psnr")]:
        assert entries[(kind, name)].distribution == "mmcsplat"
        assert entries[(kind, name)].entry_point.startswith("builtin-")
    assert not [b for b in registry.broken if b.distribution == "mmcsplat"]


def test_listing_needs_no_heavy_imports():
    result = run_python(
        """
        import sys
        from mmcsplat.configuration.registry import default_registry
        default_registry()
        heavy = [m for m in ("torch", "jax", "cv2", "zarr", "numba") if m in sys.modules]
        print(heavy)
        """
    )
    assert result.returncode == 0, result.stderr
    # torch is imported only by the availability check of torch-cuda, which the listing does not run here.
    assert result.stdout.strip() == "[]"


def test_cli_lists_every_kind_with_availability():
    result = run_cli("plugins", "--json")
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    names = {(p["kind"], p["name"]): p for p in data["plugins"]}
    assert names[("renderer", "torch-reference")]["available"] is True
    cuda = names[("renderer", "torch-cuda")]
    if not cuda["available"]:
        assert cuda["reason"] and ("CUDA" in cuda["reason"] or "gsplat" in cuda["reason"])
    text = run_cli("plugins")
    assert text.returncode == 0
    for kind in KIND_NAMES:
        assert f"{kind}:" in text.stdout


def test_third_party_initializer_selected_by_configuration(tmp_path):
    config = tmp_path / "grid.toml"
    config.write_text('[[initializer]]\nname = "example-grid"\npoints_per_axis = 3\nhalf_size = 0.2\n')
    result = run_python(
        f"""
        import numpy as np, torch
        from mmcsplat.configuration.config import load_config
        from mmcsplat.plugin_api.interfaces import SceneContext
        from mmcsplat.configuration.registry import default_registry
        entry = default_registry().get("initializer", "example-grid")
        print(entry.distribution)
        (choice,) = load_config({str(config)!r}).plugins("initializer")
        initializer = choice.build()
        scene = SceneContext(session=None, cameras=(), frame=0, center=np.array([0.0, 0.0, 0.1]), scale=1.0)
        gaussians = initializer.initial_gaussians(scene, torch.Generator().manual_seed(0))
        print(gaussians.count, float(gaussians.means[:, 2].mean()))
        """,
        THIRDPARTY / "good",
    )
    assert result.returncode == 0, result.stderr
    distribution, counts = result.stdout.strip().splitlines()
    assert distribution == "mmcsplat-example-plugin"
    count, mean_z = counts.split()
    assert int(count) == 27 and float(mean_z) == pytest.approx(0.1)


def test_broken_and_clashing_plugins_are_reported_without_breaking_others():
    result = run_cli("plugins", "--json", plugin_dirs=(THIRDPARTY / "broken", THIRDPARTY / "good"))
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    (broken,) = data["broken"]
    assert broken["distribution"] == "mmcsplat-broken-plugin"
    assert "a_dependency_that_is_not_installed" in broken["error"]
    listed = {(p["kind"], p["name"], p["distribution"]) for p in data["plugins"]}
    assert ("initializer", "example-grid", "mmcsplat-example-plugin") in listed
    assert ("renderer", "torch-reference", "mmcsplat") in listed
    psnr = [p for p in data["plugins"] if p["name"] == "psnr"]
    reasons = {p["distribution"]: p["reason"] for p in psnr}
    assert reasons["mmcsplat"] is None and "shadowed: a built-in has this name" in reasons["mmcsplat-clashing-plugin"]

    clash = run_python(  # the built-in wins, with a warning naming the other
        """
        from mmcsplat.configuration.registry import default_registry
        print(default_registry().get("metric", "psnr").distribution)
        """,
        THIRDPARTY / "broken",
    )
    assert clash.returncode == 0 and clash.stdout.strip() == "mmcsplat"
    assert "also registered by" in clash.stderr and "mmcsplat-clashing-plugin" in clash.stderr


def _module_registering(**hooks) -> types.ModuleType:
    module = types.ModuleType("fake_plugin")
    for name, registrations in hooks.items():
        setattr(module, name, hookimpl(lambda registrations=registrations: registrations))
    return module


def test_unknown_name_lists_what_is_registered():
    registry = default_registry()
    with pytest.raises(UnknownPluginError) as error:
        registry.get("renderer", "no-such-renderer")
    assert "no-such-renderer" in str(error.value) and "torch-reference" in str(error.value)
    with pytest.raises(Exception, match="unknown plugin kind"):
        registry.get("no-such-kind", "x")


def test_duplicate_within_registry_names_both_origins():
    module = _module_registering(mmcsplat_metrics=[Registration("psnr", "math:sqrt")])
    other = _module_registering(mmcsplat_metrics=[Registration("psnr", "math:cos")])
    registry = Registry(plugin_modules=[("extra", "my-dist", module), ("more", "other-dist", other)])
    with pytest.warns(UserWarning, match="also registered by"):
        assert registry.get("metric", "psnr").distribution == "mmcsplat"  # the built-in wins
    clashing = _module_registering(mmcsplat_metrics=[Registration("shared", "math:sqrt")])
    registry = Registry(plugin_modules=[("extra", "my-dist", clashing), ("more", "other-dist", _module_registering(
        mmcsplat_metrics=[Registration("shared", "math:cos")]))])
    with pytest.raises(DuplicatePluginError, match="my-dist"):  # two third-party ones: nobody wins
        registry.get("metric", "shared")


def test_a_hook_returning_something_else_is_a_broken_plugin_not_a_broken_cli():
    module = _module_registering(mmcsplat_metrics=["psnr"], mmcsplat_renderers=42)
    registry = Registry(plugin_modules=[("odd", "odd-dist", module)])
    errors = sorted(b.error for b in registry.broken if b.distribution == "odd-dist")
    assert len(errors) == 2 and "returned 'psnr', not Registration records" in errors[0] and "raised TypeError" in errors[1]
    assert registry.get("metric", "psnr").distribution == "mmcsplat"


def test_factory_import_failure_names_plugin_and_distribution():
    module = _module_registering(mmcsplat_segmenters=[Registration("ghost", "no_such_module_here:Ghost")])
    registry = Registry(plugin_modules=[("ghosts", "ghost-dist", module)])
    with pytest.raises(BrokenPluginError, match=r"segmenter 'ghost'.*ghost-dist"):
        registry.create("segmenter", "ghost")


def test_raising_hook_is_isolated():
    def explode():
        raise RuntimeError("boom")

    module = types.ModuleType("exploding")
    module.mmcsplat_dynamics = hookimpl(explode)
    registry = Registry(plugin_modules=[("exploding", "boom-dist", module)])
    assert any(b.distribution == "boom-dist" and "boom" in b.error for b in registry.broken)
    assert "torch-reference" in registry.names("renderer")


def test_unavailable_plugin_refuses_with_reason():
    module = _module_registering(
        mmcsplat_renderers=[Registration("needs-gpu", "math:sqrt", unavailable=lambda: "no CUDA device")]
    )
    registry = Registry(plugin_modules=[("gpu", "gpu-dist", module)])
    with pytest.raises(PluginUnavailableError, match="no CUDA device"):
        registry.create("renderer", "needs-gpu")


def test_bad_parameters_name_the_plugin():
    module = _module_registering(mmcsplat_metrics=[Registration("strict", "mmcsplat.plugins.metrics:PSNR")])
    registry = Registry(plugin_modules=[("strict", "strict-dist", module)])
    with pytest.raises(Exception, match=r"metric 'strict'.*rejected its parameters"):
        registry.create("metric", "strict", no_such_parameter=1)


def test_a_missing_module_names_the_extra_that_installs_it():
    from mmcsplat import needs_modules

    assert needs_modules("json")() is None
    assert needs_modules("mmcsplat_no_such_module", extra="jax")() == "needs mmcsplat_no_such_module (not installed): pip install 'mmcsplat[jax]'"
    assert needs_modules("mmcsplat_no_such_module")() == "needs mmcsplat_no_such_module (not installed)"


def test_an_unexpected_error_inside_a_plugin_names_the_plugin(tmp_path):
    """A third party's initializer that raises a plain Python error (here torch's, deep inside its call): the
    command's one line names the plugin and its distribution, not only "a defect of mmcsplat or of a plugin"."""
    from fitting_scene import write_session

    session = write_session(tmp_path / "s.zarr")
    config = tmp_path / "grid.toml"
    config.write_text('[fit]\niterations = 5\n[renderer]\nname = "torch-reference"\n'
                      '[[initializer]]\nname = "example-grid"\npoints_per_axis = -1\n')
    result = run_cli("fit", str(session), "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress",
                     plugin_dirs=(THIRDPARTY / "good",))
    assert result.returncode == 1, result.stderr
    assert ("unexpected RuntimeError in initializer plugin 'example-grid' (entry point 'example' of distribution "
            "'mmcsplat-example-plugin'): ") in result.stderr
    assert "(a defect of the plugin, or an input it does not handle;" in result.stderr


def test_the_plugin_in_a_traceback_is_its_innermost_plugin_frame():
    from mmcsplat.training.plugin_hooks import plugin_in_traceback

    module = _module_registering(mmcsplat_metrics=[Registration("exploding", f"{__name__}:Exploding")])
    registry = Registry(plugin_modules=[("extra", "my-dist", module)])
    try:
        Exploding()()
    except ZeroDivisionError as error:
        assert plugin_in_traceback(error, registry.entries) == "metric plugin 'exploding' (entry point 'extra' of distribution 'my-dist')"
        assert plugin_in_traceback(error, Registry(plugin_modules=[]).entries) is None  # no frame of a plugin's


class Exploding:
    def __call__(self):
        return [1][0] / 0
