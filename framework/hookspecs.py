"""The hook specifications a plugin module implements: the documented contract of an mmcsplat plugin.

A plugin module is named by an entry point in the ``mmcsplat`` group of its distribution's metadata::

    [project.entry-points.mmcsplat]
    my-initializers = "my_package.mmcsplat_plugin"

and implements one or more of the hooks below with ``@mmcsplat.hookimpl``. Each hook returns a list of
:class:`~mmcsplat.registry.Registration`: a name, the ``"module:attribute"`` of a factory (imported only
when the implementation is used, so listing plugins stays fast and never imports torch or jax), and an
optional availability check. The interface each factory must produce is in :mod:`mmcsplat.interfaces`.
"""

from __future__ import annotations

import pluggy

from .registry import Registration

PROJECT = "mmcsplat"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def mmcsplat_renderers() -> list[Registration]:
    """Renderer backends; each factory returns a :class:`~mmcsplat.interfaces.Renderer`."""


@hookspec
def mmcsplat_segmenters() -> list[Registration]:
    """Segmenters; each factory returns a :class:`~mmcsplat.interfaces.Segmenter`."""


@hookspec
def mmcsplat_initializers() -> list[Registration]:
    """Initializers; each factory returns an :class:`~mmcsplat.interfaces.Initializer`."""


@hookspec
def mmcsplat_depth_sources() -> list[Registration]:
    """Depth maps for the ``depth-supervised`` initializer; each factory returns a
    :class:`~mmcsplat.interfaces.DepthSource`."""


@hookspec
def mmcsplat_densifiers() -> list[Registration]:
    """Densification strategies; each factory returns a :class:`~mmcsplat.interfaces.Densifier`."""


@hookspec
def mmcsplat_dynamics() -> list[Registration]:
    """Dynamics methods; each factory returns a :class:`~mmcsplat.interfaces.Dynamics`."""


@hookspec
def mmcsplat_readers() -> list[Registration]:
    """Dataset readers (capture formats); each factory returns a :class:`~mmcsplat.interfaces.Reader`."""


@hookspec
def mmcsplat_metrics() -> list[Registration]:
    """Metrics; each factory returns a :class:`~mmcsplat.interfaces.Metric`."""


#: Plugin kind → the hook that registers it.
HOOK_OF_KIND = {
    "renderer": "mmcsplat_renderers",
    "segmenter": "mmcsplat_segmenters",
    "initializer": "mmcsplat_initializers",
    "depth-source": "mmcsplat_depth_sources",
    "densifier": "mmcsplat_densifiers",
    "dynamics": "mmcsplat_dynamics",
    "reader": "mmcsplat_readers",
    "metric": "mmcsplat_metrics",
}
