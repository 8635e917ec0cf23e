"""Reliability, plugins: a renderer plugin that raises in its constructor, returns wrong shapes or NaN
is an error naming it (the cheap render-contract checks run on every call)."""

from __future__ import annotations

import types

import pytest
import torch
from fitting_scene import write_config, write_session

from mmcsplat import Registration, hookimpl
from mmcsplat.backends.torch_reference import TorchReferenceRenderer
from mmcsplat.configuration.config import load_config
from mmcsplat.configuration.registry import Registry
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.plugin_api.errors import PluginError
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
