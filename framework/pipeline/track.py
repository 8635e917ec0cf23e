"""Dynamic tracking of a first-frame fit: a ``dynamics`` plugin carries the fitted Gaussians through the
rest of the session and writes ``RUN/tracks.zarr``; ``RUN/track.json`` records what ran and how long.

The configuration is the one the run was fitted with (``run.json``), or another one given explicitly;
its ``[dynamics]`` table (or ``--dynamics NAME``) chooses the method and its parameters, and its ``[fit]``
table and initializers give the image loss (weights, background, masked targets) the frames are fitted
with, so tracking sees the same targets as the first frame did.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.configuration.config import Config, ConfigError, PluginChoice, apply_overrides, load_config
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.plugin_api.errors import InputError, OutputExistsError, PluginError
from mmcsplat.plugin_api.interfaces import Dynamics, TrackingContext
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.completeness import remove_made_before
from mmcsplat.storage.locking import run_lock
from mmcsplat.storage.run import RUN_INFO, TRACK_INFO, TRACKING_UNFINISHED, TRACKS_DIR
from mmcsplat.storage.run_info import RunInfo
from mmcsplat.storage.run_log import run_log
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import stamp_recording, tracks_token
from mmcsplat.training.backdrop import camera_backdrop
from mmcsplat.training.fitted_run import FittedRun
from mmcsplat.training.plugin_hooks import plugin_hook
from mmcsplat.training.settings import FitSettings
from mmcsplat.training.supersampling import run_renderer
from mmcsplat.training.views import load_views

#: The method ``track`` runs when neither ``--dynamics`` nor the configuration's [dynamics] table names one
#: — the built-in configurations are first-frame ones and have none — as ``mmcsplat demo`` and ``run`` do.
DEFAULT_DYNAMICS = "iterative"


def tracking_config(
    run: Path, info: RunInfo, config: str | Path | None, overrides: Iterable[str], dynamics: str | None
) -> tuple[Config, PluginChoice]:
    """The configuration to track with (``config``, else the one ``run`` was fitted with, from its run.json
    ``info``) after ``overrides``, and its dynamics choice: ``dynamics``, else the method the ``[dynamics]``
    table names, else :data:`DEFAULT_DYNAMICS`; the table's parameters are kept when it names the chosen
    method or none (``--set dynamics.iterations=300`` alone tunes the default)."""
    if config is not None:
        loaded = load_config(config, overrides)
    else:
        source = f"the configuration of {Path(run) / RUN_INFO}"
        loaded = Config(source, apply_overrides(info.config_values, overrides, source))
    return loaded, dynamics_choice(loaded, dynamics)


def dynamics_choice(loaded: Config, dynamics: str | None = None) -> PluginChoice:
    """The dynamics method of ``loaded``: ``dynamics``, else the one its ``[dynamics]`` table names, else
    :data:`DEFAULT_DYNAMICS`; the table's parameters are kept when it names that method or none."""
    table = loaded.values.get("dynamics", {})
    if not isinstance(table, Mapping) or not isinstance(table.get("name", ""), str):
        raise ConfigError(f"{loaded.source}: [dynamics] must be one table with a string 'name'")
    method = dynamics or table.get("name") or DEFAULT_DYNAMICS
    params = {key: value for key, value in table.items() if key != "name"} if table.get("name", method) == method else {}
    return PluginChoice("dynamics", method, params)


def require_cameras_per_frame(run: Path, session: SessionReader, cameras: Iterable[str], frames: range, method: str, needed: int) -> None:
    """Refuse a dynamics method that needs ``needed`` training cameras at a frame on a capture whose
    ``frames`` mostly hold fewer (one moving camera: a monocular capture), naming a method that can."""
    counts = np.sum([session.present(name)[frames.start : frames.stop] for name in cameras], axis=0)
    if needed > 1 and np.median(counts) < needed:
        raise InputError(f"{run}: dynamics {method!r} fits each frame from that frame's own images and needs {needed} training cameras "
                         f"at a frame, but session {session.url!r} images most frames with {int(np.median(counts))} (one moving camera?): "
                         "track it with --dynamics deformation, which trains over every (frame, camera) image of the sequence")


def track_run(
    run: Path,
    *,
    config: str | Path | None = None,
    overrides: Iterable[str] = (),
    dynamics: str | None = None,
    backend: str | None = None,
    registry: Registry | None = None,
    progress: bool = True,
    overwrite: bool = False,
    frames: slice | None = None,
) -> dict[str, Any]:
    """Track the first-frame fit in ``run`` through its session — through the session frames ``frames``
    when given, a range that starts at the fitted frame (or leaves its start out) with step 1 — and write
    RUN/tracks.zarr and RUN/track.json (returned)."""
    run = Path(run)
    registry = registry or default_registry()
    fitted = FittedRun.load(run)
    fitted.require_complete()
    info = fitted.info
    loaded, choice = tracking_config(run, info, config, overrides, dynamics)
    method: Dynamics = choice.build(registry)
    session = fitted.session
    settings = FitSettings.from_config(loaded)
    first = info.frame
    frames = frames or slice(None)
    if frames.start not in (None, first) or frames.step not in (None, 1):
        raise InputError(f"{run}: --frames {frames.start or ''}:{frames.stop or ''}{':' + str(frames.step) if frames.step else ''} — tracking "
                         f"runs on from the fitted frame {first}, one frame at a time: give {first}:STOP or :STOP")
    stop = session.num_frames if frames.stop is None else min(session.num_frames, frames.stop)
    if stop - first < 2:
        raise InputError(f"{run}: frames {first}–{stop - 1} of session {session.url!r} leave nothing to track after the fitted frame")
    require_cameras_per_frame(run, session, info.train_cameras, range(first, stop), choice.name, method.cameras_per_frame)
    if (run / TRACKS_DIR).exists() and not overwrite:  # after the settings' checks: a bad value is named first
        raise OutputExistsError(f"{run / TRACKS_DIR} already exists (use --overwrite to replace it)")
    renderer_name = backend or info.renderer
    cameras = tuple(session.camera(name) for name in info.train_cameras)
    initializers = tuple(c.build(registry) for c in loaded.plugins("initializer"))
    backdrops = tuple(camera_backdrop(settings.background, session, name) for name in info.train_cameras)

    context = TrackingContext(
        session=session,
        cameras=cameras,
        heldout=tuple(session.camera(name) for name in info.heldout_cameras),
        frames=range(first, stop),
        params=fitted.params,
        camera_scale=fitted.camera_scale,
        camera_offset=fitted.camera_offset,
        renderer=run_renderer(info, registry, renderer_name),
        settings=settings,
        initializers=initializers,
        backdrops=backdrops,
        scene_center=info.scene_center,
        scene_scale=info.scene_scale,
        plugins=registry,
        views=lambda t: load_views(session, t, cameras, initializers, backdrops, settings),
        progress=progress,
        overwrite=overwrite,
    )
    defaulted = dynamics is None and not loaded.get("dynamics.name")
    with run_lock(run), run_log(run) as log:
        log.info("track with %s %s%s over session frames %d–%d, renderer %s", choice.name, dict(choice.params),
                 " (the default: the configuration names no dynamics method)" if defaulted else "", first, stop - 1, renderer_name)
        began = time.perf_counter()
        before = tracks_token(run)
        write_json_atomic(run / TRACKING_UNFINISHED, {"method": choice.name, "frames": [first, stop]})
        try:
            with plugin_hook("dynamics", choice.name, "track"):
                summary = method.track(context, run)
            if tracks_token(run) in (None, before):
                raise PluginError(f"dynamics plugin {choice.name!r} returned from track() without writing its tracks "
                                  f"({run / TRACKS_DIR}): a defect of the plugin")
            stamp_recording(run, session.fingerprint, fitted.digest)
        except BaseException as error:
            context.curve.write(run)  # what was logged before the stop: a failed track's curve shows why
            log.error("tracking stopped: %s", f"{type(error).__name__}: {error}" if str(error) else type(error).__name__)
            raise
        wall = time.perf_counter() - began
        context.curve.write(run)
        log.info("tracked %d frames in %.1f s", len(context.frames), wall)
        # Until the marker below goes, export and evaluate refuse the run: a kill here leaves nothing read as current.
        removed = remove_made_before(run)
        if removed:
            log.info("removed what was made before these tracks: %s", ", ".join(removed))
        record = {
            "method": choice.name,
            "method_default": defaulted,
            "params": dict(choice.params),
            "config": loaded.source,
            "renderer": renderer_name,
            "frames": [context.frames.start, context.frames.stop],
            "wall_s": round(wall, 3),
            "wall_s_per_frame": round(wall / (len(context.frames) - 1), 3),
            "summary": summary,
            "recording": session.fingerprint,
            "removed": removed,
        }
        write_json_atomic(run / TRACK_INFO, record)
        (run / TRACKING_UNFINISHED).unlink()
    return record
