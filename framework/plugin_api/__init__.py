"""The public API for plugins: everything a plugin may import from the core, and nothing else.

A plugin module implements hooks of :mod:`.hookspecs` with :data:`hookimpl`, returning
:class:`Registration` records; its factories build objects implementing the interfaces of
:mod:`.interfaces` (with the records they receive: scene, training view, tracking context), and use the
render contract types of :mod:`.render_contract`. Plugins may also use the public value types of :mod:`mmcsplat.scene`, the
formats of :mod:`mmcsplat.storage` and the shared training pieces of :mod:`mmcsplat.training`.

Names are imported on first use, so that listing plugins never imports torch.
"""

from __future__ import annotations

import importlib
from typing import Any

from .hookspecs import hookimpl
from .registration import Registration, needs_modules

_LAZY = {
    "Kind": "kinds",
    "KINDS": "kinds",
    "KIND_NAMES": "kinds",
    "MmcsplatError": "errors",
    "PluginError": "errors",
    "UnknownPluginError": "errors",
    "DuplicatePluginError": "errors",
    "BrokenPluginError": "errors",
    "PluginUnavailableError": "errors",
    "InputError": "errors",
    "MissingFileError": "errors",
    "Reader": "interfaces",
    "Recording": "interfaces",
    "RecordedFrame": "interfaces",
    "Renderer": "interfaces",
    "Segmenter": "interfaces",
    "Initializer": "interfaces",
    "DepthSource": "interfaces",
    "Densifier": "interfaces",
    "Dynamics": "interfaces",
    "Metric": "interfaces",
    "LandmarkSource": "interfaces",
    "Landmarks": "interfaces",
    "KeypointObservations": "interfaces",
    "SceneContext": "interfaces",
    "RegionChoice": "interfaces",
    "TrainingView": "interfaces",
    "TrackingContext": "interfaces",
    "Gaussians": "render_contract",
    "RenderCameras": "render_contract",
    "RenderOutput": "render_contract",
}

__all__ = ["Registration", "hookimpl", "needs_modules", *_LAZY]


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
