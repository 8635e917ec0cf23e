"""Reliability, plugins: a renderer plugin that raises in its constructor, returns wrong shapes or NaN
is an error naming it (the cheap render-contract checks run on every call)."""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch
from fitting_scene import write_config, write_fitted_run, write_session

from mmcsplat import Registration, hookimpl
from mmcsplat.backends.torch_reference import TorchReferenceRenderer
from mmcsplat.configuration.config import load_config
from mmcsplat.configuration.registry import Registry
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.pipeline.track import track_run
from mmcsplat.plugin_api.errors import PluginError
from mmcsplat.plugin_api.interfaces import Dynamics, Segmenter
from mmcsplat.plugin_api.render_contract import RenderOutput
from mmcsplat.storage.session import SessionReader


class Exploding:
    def __init__(self) -> None:
        raise RuntimeError("no such device")


class WrongShapes(TorchReferenceRenderer):
    def render(self, gaussians, cameras, background=None):
        output = super().render(gaussians, cameras, background)
        return RenderOutput(output.rgb[..., :2], output.features, output.depth, output.alpha, output.radii, output.means2d)


class NotANumber(TorchReferenceRenderer):
    def render(self, gaussians, cameras, background=None):
        output = super().render(gaussians, cameras, background)
        return RenderOutput(output.rgb * torch.nan, output.features, output.depth, output.alpha, output.radii, output.means2d)


def _registry() -> Registry:
    module = types.ModuleType("odd_renderers")
    module.mmcsplat_renderers = hookimpl(lambda: [Registration(name, f"{__name__}:{factory}") for name, factory in
                                                  (("exploding", "Exploding"), ("wrong-shapes", "WrongShapes"), ("nan", "NotANumber"))])
    return Registry(plugin_modules=[("odd", "odd-renderers", module)])


@pytest.mark.parametrize("name, message", [
    ("exploding", "renderer 'exploding' from entry point 'odd' of distribution 'odd-renderers' failed to build: RuntimeError\\('no such device'\\)"),
    ("wrong-shapes", r"renderer 'wrong-shapes' returned rgb of shape \[1, 36, 48, 2\] .* the contract is \[1, 36, 48, 3\]"),
    ("nan", "renderer 'nan' returned a non-finite rgb from finite Gaussians and cameras"),
])
def test_a_faulty_renderer_is_named(tmp_path, name, message):
    session = SessionReader(write_session(tmp_path / "s.zarr"))
    config = load_config(write_config(tmp_path / "fit.toml", iterations=3))
    with pytest.raises(PluginError, match=message):
        FirstFrameFit(session, config, tmp_path / "run", backend=name, registry=_registry(), progress=False).run()


# ----------------------------------------------------------------------- failures while plugins run


class RaisingRenderer(TorchReferenceRenderer):
    def render(self, gaussians, cameras, background=None):
        raise RuntimeError("kernel launch failed")


class Lazy(Dynamics):
    """Returns as if it had tracked, writing nothing."""

    def track(self, context, out):
        return {}


class Crashing(Dynamics):
    def track(self, context, out):
        raise ZeroDivisionError("division by zero")


class CrashingSegmenter(Segmenter):
    def segment(self, session, camera):
        yield 0, np.ones((session.camera(camera).height, session.camera(camera).width), dtype=bool), None
        raise KeyError("frame 1 model weights")


def _runtime_registry() -> Registry:
    module = types.ModuleType("odd_runtime")
    module.mmcsplat_renderers = hookimpl(lambda: [Registration("raising", f"{__name__}:RaisingRenderer")])
    module.mmcsplat_dynamics = hookimpl(lambda: [Registration("lazy", f"{__name__}:Lazy"), Registration("crashing", f"{__name__}:Crashing")])
    module.mmcsplat_segmenters = hookimpl(lambda: [Registration("crashing", f"{__name__}:CrashingSegmenter")])
    return Registry(plugin_modules=[("odd", "odd-runtime", module)])


def test_a_renderer_raising_while_it_renders_is_named_with_its_hook(tmp_path):
    session = SessionReader(write_session(tmp_path / "s.zarr"))
    config = load_config(write_config(tmp_path / "fit.toml", iterations=3))
    with pytest.raises(PluginError, match=r"^renderer plugin 'raising' failed in render\(\): RuntimeError: kernel launch failed"):
        FirstFrameFit(session, config, tmp_path / "run", backend="raising", registry=_runtime_registry(), progress=False).run()


@pytest.mark.parametrize("name, message", [
    ("lazy", r"dynamics plugin 'lazy' returned from track\(\) without writing its tracks \(.*tracks.zarr\)"),
    ("crashing", r"dynamics plugin 'crashing' failed in track\(\): ZeroDivisionError: division by zero"),
])
def test_a_dynamics_plugin_that_fails_or_writes_nothing_is_named(tmp_path, name, message):
    session = write_session(tmp_path / "s.zarr", frames=2)
    run = write_fitted_run(tmp_path / "run", session)
    with pytest.raises(PluginError, match=message):
        track_run(run, dynamics=name, registry=_runtime_registry(), progress=False)
    assert not (run / "track.json").exists() and not (run / "tracks.zarr").exists()
    assert (run / "tracking.unfinished").exists()  # evaluate, report, landmarks and export refuse the run until it is tracked


def test_a_segmenter_raising_while_it_segments_is_named_with_its_hook(tmp_path, monkeypatch):
    import mmcsplat.pipeline.segment as segment_module

    session = write_session(tmp_path / "s.zarr", frames=2, masks=False)
    monkeypatch.setattr(segment_module, "default_registry", _runtime_registry)
    with pytest.raises(PluginError, match=r"segmenter plugin 'crashing' failed in segment\(\): KeyError: 'frame 1 model weights'"):
        segment_module.segment_session(session, "crashing", progress=False)
    assert not SessionReader(session).has("mask")
