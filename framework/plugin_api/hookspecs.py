"""The hook specifications a plugin module implements: the documented contract of an mmcsplat plugin.

A plugin module is named by an entry point in the ``mmcsplat`` group of its distribution's metadata::

    [project.entry-points.mmcsplat]
    my-initializers = "my_package.mmcsplat_plugin"

and implements one or more of the hooks below with ``@hookimpl``. Each hook returns a list of
:class:`~mmcsplat.plugin_api.registration.Registration`: a name, the ``"module:attribute"`` of a factory
(imported only when the implementation is used, so listing plugins stays fast), and an optional
availability check. The interface each factory must produce is in :mod:`mmcsplat.plugin_api.interfaces`;
:mod:`mmcsplat.plugin_api.kinds` pairs each kind with its hook and interface.

Like pytest's hookspec module, this one imports only pluggy when it runs; the types it names are for type
checkers.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from .registration import Registration

PROJECT = "mmcsplat"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def mmcsplat_renderers() -> list[Registration]:
    """Renderer backends; each factory returns a :class:`~mmcsplat.plugin_api.interfaces.Renderer`."""


@hookspec
def mmcsplat_segmenters() -> list[Registration]:
    """Segmenters; each factory returns a :class:`~mmcsplat.plugin_api.interfaces.Segmenter`."""


@hookspec
def mmcsplat_initializers() -> list[Registration]:
    """Initializers; each factory returns an :class:`~mmcsplat.plugin_api.interfaces.Initializer`."""


@hookspec
def mmcsplat_depth_sources() -> list[Registration]:
    """Depth maps for the ``depth-supervised`` initializer; each factory returns a
    :class:`~mmcsplat.plugin_api.interfaces.DepthSource`."""


@hookspec
def mmcsplat_densifiers() -> list[Registration]:
    """Densification strategies; each factory returns a :class:`~mmcsplat.plugin_api.interfaces.Densifier`."""


@hookspec
def mmcsplat_dynamics() -> list[Registration]:
    """Dynamics methods; each factory returns a :class:`~mmcsplat.plugin_api.interfaces.Dynamics`."""


@hookspec
def mmcsplat_readers() -> list[Registration]:
    """Dataset readers (capture formats); each factory returns a :class:`~mmcsplat.plugin_api.interfaces.Reader`."""


@hookspec
def mmcsplat_metrics() -> list[Registration]:
    """Metrics; each factory returns a :class:`~mmcsplat.plugin_api.interfaces.Metric`."""


@hookspec
def mmcsplat_landmarks() -> list[Registration]:
    """Landmark sources (named 3D points: files, triangulated keypoints, ground truth); each factory
    returns a :class:`~mmcsplat.plugin_api.interfaces.LandmarkSource`."""
