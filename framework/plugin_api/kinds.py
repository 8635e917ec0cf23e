"""The one table of plugin kinds: each kind's name, the hook that registers it and the interface its
factories return. The registry, ``mmcsplat plugins`` and the docs read it; a test checks that every hook
it names is specified in :mod:`mmcsplat.plugin_api.hookspecs`. A leaf module: interfaces are named, and
imported only when asked for, so that the registry stays light and the interfaces may name what the
registry builds."""

from __future__ import annotations

import importlib

import attrs


@attrs.frozen
class Kind:
    """One plugin kind: its ``name`` in configurations, its ``hook`` and the name of its interface in
    :mod:`mmcsplat.plugin_api.interfaces`."""

    name: str
    hook: str
    interface_name: str

    @property
    def interface(self) -> type:
        """The interface class its factories return."""
        return getattr(importlib.import_module("mmcsplat.plugin_api.interfaces"), self.interface_name)


KINDS: tuple[Kind, ...] = (
    Kind("renderer", "mmcsplat_renderers", "Renderer"),
    Kind("segmenter", "mmcsplat_segmenters", "Segmenter"),
    Kind("initializer", "mmcsplat_initializers", "Initializer"),
    Kind("depth-source", "mmcsplat_depth_sources", "DepthSource"),
    Kind("densifier", "mmcsplat_densifiers", "Densifier"),
    Kind("dynamics", "mmcsplat_dynamics", "Dynamics"),
    Kind("reader", "mmcsplat_readers", "Reader"),
    Kind("metric", "mmcsplat_metrics", "Metric"),
    Kind("landmarks", "mmcsplat_landmarks", "LandmarkSource"),
)

#: The kinds' names, in the order listings show them.
KIND_NAMES: tuple[str, ...] = tuple(kind.name for kind in KINDS)

