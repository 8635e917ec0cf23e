"""What tracking hands a dynamics method: plain records and a plugin builder, not the pipeline's whole
configuration or its concrete registry."""

from __future__ import annotations

import types

import attrs
from fitting_scene import write_fitted_run, write_session

from mmcsplat import Registration, hookimpl
from mmcsplat.configuration.registry import Registry
from mmcsplat.pipeline.track import track_run
from mmcsplat.plugin_api.interfaces import Densifier, Dynamics, TrackingContext
from mmcsplat.storage.tracks import TrackWriter

MOVING = ("means", "quats")


class MarkedDensifier(Densifier):
    """A densifier only the test's registry holds: the dynamics method below can build it only through
    the builder the pipeline hands it."""

    def initialize_state(self, scene_scale: float) -> dict:
        return {"scene_scale": scene_scale}

    def step_post_backward(self, model, state, step, render) -> None:
        """Changes nothing: the test only builds it."""


class DensifierBuildingDynamics(Dynamics):
    """Builds its densifier by name from the context, as the ``deformation`` method does, and reports what it got."""

    def track(self, context: TrackingContext, out) -> dict:
        densifier = context.plugins.create("densifier", "marked")
        static = {name: value for name, value in context.params.items() if name not in MOVING}
        with TrackWriter(out, num_frames=len(context.frames), static=static, method="densifier-building") as writer:
            for k in range(len(context.frames)):  # tracks it must write: the fitted Gaussians held still
                writer.write_frame(k, **{name: context.params[name] for name in MOVING})
        return {"densifier": type(densifier).__name__, "state": densifier.initialize_state(context.scene_scale)}


def test_a_dynamics_method_builds_the_plugins_it_names_through_the_context(tmp_path):
    assert not {"config", "registry"} & {field.name for field in attrs.fields(TrackingContext)}
    plugin = types.ModuleType("marked_plugins")
    plugin.mmcsplat_densifiers = hookimpl(lambda: [Registration("marked", f"{__name__}:MarkedDensifier")])
    plugin.mmcsplat_dynamics = hookimpl(lambda: [Registration("densifier-building", f"{__name__}:DensifierBuildingDynamics")])
    registry = Registry([("marked", "test-dist", plugin)])
    session = write_session(tmp_path / "s.zarr", frames=3)
    run = write_fitted_run(tmp_path / "run", session)
    record = track_run(run, dynamics="densifier-building", registry=registry, progress=False)
    assert record["summary"]["densifier"] == "MarkedDensifier"
    assert record["summary"]["state"]["scene_scale"] > 0
