"""The first-frame fit: Gaussians optimised against the training cameras of one frame.

Every choice comes from the configuration through the registry: the renderer, the composed initializers,
the densifier. The run directory holds an atomic checkpoint (a killed run resumes from it), ``run.json``
(what was fitted, how long it took, how it ended, the loss record of :class:`BlockLosses`, warnings)
and the final Gaussians.
"""

from __future__ import annotations

import copy
import logging
import re
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
import torch

from mmcsplat.configuration.config import Config, PluginChoice
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Densifier, Initializer, Renderer, SceneContext, TrainingView
from mmcsplat.plugin_api.render_contract import RenderCameras
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.rig import rig_center, rig_scale
from mmcsplat.storage.atomic import signals_deferred
from mmcsplat.storage.completeness import remove_made_before
from mmcsplat.storage.curves import TrainingCurve
from mmcsplat.storage.locking import run_lock
from mmcsplat.storage.run import CHECKPOINT
from mmcsplat.storage.run_info import COMPLETE, DIVERGED, RUNNING, RunInfo
from mmcsplat.storage.run_log import run_log
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.backdrop import camera_backdrop
from mmcsplat.training.checked_renderer import CheckedRenderer
from mmcsplat.training.checkpoint import resume_checkpoint, save_checkpoint
from mmcsplat.training.finite import FitError
from mmcsplat.training.loop import Sample, Step, TrainingLoop, initializer_pruning, initializer_terms
from mmcsplat.training.model import GaussianModel
from mmcsplat.training.schedule import CameraSchedule
from mmcsplat.training.settings import FitSettings
from mmcsplat.training.supersampling import supersampled
from mmcsplat.training.views import first_fit_images, load_view, require_masks, subject_warnings


@attrs.define
class BlockLosses:
    """The loss and PSNR averaged over each block of ``size`` iterations — one block of the camera schedule,
    every training camera once — whose lowest (``lowest``) and latest (``last``) complete loss means
    run.json records as ``loss_min`` and ``loss_final``, and whose means are the fit's rows of
    ``RUN/curves.csv``. Single iterations each see another camera, so their losses differ by the camera
    more than by the training; block means compare. A blow-up is a final mean far above the lowest. Saved
    in the checkpoint, so a resumed fit records the same."""

    size: int
    total: float = 0.0
    psnr_total: float = 0.0
    count: int = 0
    lowest: float | None = None
    last: float | None = None

    def add(self, loss: float, psnr: float) -> tuple[float, float] | None:
        """Count one iteration; returns the block's (mean loss, mean PSNR) when it completes the block."""
        self.total += loss
        self.psnr_total += psnr
        self.count += 1
        if self.count < self.size:
            return None
        self.last = self.total / self.size
        self.lowest = self.last if self.lowest is None else min(self.lowest, self.last)
        means = self.last, self.psnr_total / self.size
        self.total, self.psnr_total, self.count = 0.0, 0.0, 0
        return means


def select_cameras(session: SessionReader, holdout: Sequence[str] | None) -> tuple[list[Camera], list[Camera]]:
    """(training cameras, held-out cameras): ``holdout`` overrides the session's own held-out list."""
    held = list(session.heldout if holdout is None else holdout)
    unknown = [name for name in held if name not in session.camera_names]
    if unknown:
        raise InputError(f"held-out camera(s) {unknown} not in session {session.url}; its cameras: {list(session.camera_names)}")
    train = [session.camera(name) for name in session.camera_names if name not in held]
    if len(train) < 2:
        raise InputError(f"a fit needs at least two training cameras; session has {list(session.camera_names)}, held out {held}")
    return train, [session.camera(name) for name in held]


def renderer_choice(config: Config, backend: str | None = None) -> PluginChoice:
    """The renderer a fit of ``config`` uses: the configuration's ``[renderer]``, or ``backend`` when named — with
    that table's parameters when it names the same renderer, else at its defaults (the table's parameters are
    another renderer's: said, not used)."""
    if not backend:
        return config.plugin("renderer")
    configured = config.plugins("renderer")
    if configured and configured[0].name == backend:
        return configured[0]
    if configured and configured[0].params:
        warnings.warn(f"--backend {backend}: the configuration's [renderer] parameters ({', '.join(sorted(configured[0].params))}) are "
                      f"{configured[0].name!r}'s and are not used", stacklevel=2)
    return PluginChoice("renderer", backend)


def with_renderer(config: Config, renderer: PluginChoice) -> Config:
    """``config`` with ``renderer`` as its ``[renderer]`` table: what a run records is what rendered it."""
    return Config(config.source, {**config.values, "renderer": {"name": renderer.name, **renderer.params}})


class FirstFrameFit:
    """One first-frame fit, configured by a :class:`Config`; ``run()`` trains (resuming if possible).

    Start and pruning regions too small for the subject's visual hull are grown by their initializers
    before anything trains (:attr:`grown_regions` says how); ``grow_regions=False`` keeps them as
    configured, and the initializer then refuses one that does not hold the subject."""

    def __init__(
        self,
        session: SessionReader,
        config: Config,
        out: Path,
        holdout: Sequence[str] | None = None,
        backend: str | None = None,
        registry: Registry | None = None,
        progress: bool = True,
        grow_regions: bool = True,
    ) -> None:
        if re.match(r"[A-Za-z][A-Za-z0-9+.-]+:/", str(out)):  # a URL, even once Path() has folded its '//'
            raise InputError(f"--out {out}: a run directory is a local folder, not a URL (sessions may be URLs, runs may not)")
        self.session = session
        self.config = config
        self.out = Path(out)
        self.settings = FitSettings.from_config(config)
        if self.settings.frame >= session.num_frames:
            raise InputError(f"{config.source}: fit.frame {self.settings.frame} is past the last frame of session {session.url} "
                             f"(it has {session.num_frames}: 0–{session.num_frames - 1})")
        self.registry = registry or default_registry()
        self.progress = progress
        self.resumed_from: int | None = None
        renderer = renderer_choice(config, backend)
        self.renderer_choice = renderer
        plugin = CheckedRenderer(renderer.build(self.registry), renderer.name)
        self.renderer: Renderer = supersampled(plugin, self.settings.supersample)
        self.initializers: list[Initializer] = [choice.build(self.registry) for choice in config.plugins("initializer")]
        densifiers = config.plugins("densifier")
        self.densifier: Densifier | None = densifiers[0].build(self.registry) if densifiers else None
        self.train_cameras, self.heldout_cameras = select_cameras(session, holdout)
        center = rig_center(session.cameras)
        self.images = first_fit_images(session, self.train_cameras, self.settings.frame, self.settings.window)
        first_seen: dict[int, int] = {}  # training camera number → the first frame the fit trains it on
        for t, index in self.images:
            first_seen.setdefault(index, t)
        self.image_frames = sorted({t for t, _ in self.images})
        self.scene = SceneContext(session, tuple(self.train_cameras[index] for index in first_seen), self.settings.frame, center,
                                  rig_scale(session.cameras, center), tuple(first_seen.values()) if len(self.image_frames) > 1 else ())
        #: One line per start or pruning region grown to hold the subject (also in run.json's warnings).
        self.grown_regions = self._grow_regions() if grow_regions else []
        self.views = self._load_views()
        self.warnings += self.grown_regions

    def _grow_regions(self) -> list[str]:
        """Let each initializer grow a start or pruning region too small for the subject
        (:meth:`~mmcsplat.plugin_api.interfaces.Initializer.fit_region`) and build it again with the size it
        chose; the configuration — run.json's record, the checkpoint's key, what tracking rebuilds — then
        holds the values in force. Returns what was grown."""
        values = copy.deepcopy(dict(self.config.values))
        section = values.get("initializer")
        tables = section if isinstance(section, list) else [section]
        grown, notes = [], []
        for index, (choice, initializer) in enumerate(zip(self.config.plugins("initializer"), self.initializers)):
            region = initializer.fit_region(self.scene)
            if region is not None:
                tables[index][region.parameter] = region.chosen
                grown.append(index)
                notes.append(f"initializer {choice.name!r}: {region.describe()}")
        if grown:
            self.config = Config(self.config.source, values)
            choices = self.config.plugins("initializer")
            for index in grown:
                self.initializers[index] = choices[index].build(self.registry)
        return notes

    def _load_views(self) -> list[TrainingView]:
        frame = self.settings.frame
        views = [
            load_view(self.session, t, self.train_cameras[index], index, self.initializers,
                      camera_backdrop(self.settings.background, self.session, self.train_cameras[index].name))
            for t, index in self.images
        ]
        require_masks(views, self.settings, self.session, frame)
        self.warnings = subject_warnings(views, frame)
        imaged = {index for _, index in self.images}
        absent = [camera.name for index, camera in enumerate(self.train_cameras) if index not in imaged]
        if absent and len(self.image_frames) == 1:
            self.warnings.append(f"no image of frame {frame} from {', '.join(absent)} (a moment missed): the first fit trains on the "
                                 "other cameras, and tracking uses each from the next frame it holds")
            warnings.warn(self.warnings[-1], stacklevel=2)
        return views

    # ------------------------------------------------------------------------------------------ setup

    def _initial_model(self, generator: torch.Generator) -> GaussianModel:
        for initializer in self.initializers:
            gaussians = initializer.initial_gaussians(self.scene, generator)
            if gaussians is not None:
                break
        else:
            raise InputError(f"{self.config.source}: no [[initializer]] places initial Gaussians (e.g. 'random' or 'visual-hull')")
        if gaussians.count == 0:
            raise InputError(f"{self.config.source}: the initializers placed no Gaussians")
        return GaussianModel(gaussians, tuple(c.name for c in self.train_cameras), self.settings.lrs, self.scene.scale)

    def _render_cameras(self) -> tuple[RenderCameras, ...]:
        return RenderCameras.each(self.train_cameras)

    # -------------------------------------------------------------------------------------- training

    def run(self) -> RunInfo:
        """Train to ``settings.iterations`` (resuming from a checkpoint in ``out``); returns run.json's
        record. A second fit into the same ``out`` while this one runs is refused."""
        self.out.mkdir(parents=True, exist_ok=True)
        with run_lock(self.out), run_log(self.out) as log:
            log.info("fit of session %s with %s into %s: %d iterations, renderer %s, training cameras %s, held out %s",
                     self.session.url, self.config.source, self.out, self.settings.iterations, self.renderer_choice.name,
                     ", ".join(c.name for c in self.train_cameras), ", ".join(c.name for c in self.heldout_cameras) or "none")
            if len(self.image_frames) > 1:
                log.info("a moving camera: the first fit trains on %d images of frames %d–%d", len(self.images), self.image_frames[0],
                         self.image_frames[-1])
            for warning in self.warnings:  # shown on the console as a Python warning already
                log.info("warning: %s", warning)
            try:
                info = self._train()
            except BaseException as error:
                log.error("fit stopped: %s", f"{type(error).__name__}: {error}" if str(error) else type(error).__name__)
                raise
            log.info("fit %s: %d iterations, %d Gaussians, %.1f s, lowest block loss %s", info.status, info.iterations,
                     info.num_gaussians, info.wall_s, info.loss_min)
            return info

    def _train(self) -> RunInfo:
        settings = self.settings
        generator = torch.Generator().manual_seed(settings.seed)
        model = self._initial_model(generator)
        schedule = CameraSchedule(len(self.views), generator)
        record = BlockLosses(len(self.views))
        curve = TrainingCurve("fit")
        densify_state = self.densifier.initialize_state(self.scene.scale) if self.densifier else {}
        start, elapsed = 0, 0.0
        checkpoint = self.out / CHECKPOINT
        if checkpoint.exists():
            start, elapsed, record, curve.rows = self._resume(checkpoint, model, generator, schedule, densify_state)
            self.resumed_from = start
            logging.getLogger(__name__).info("resumed from the checkpoint at iteration %d", start)
            # Made with --allow-incomplete of the fit stopped half way (a complete fit run again changes nothing).
            removed = remove_made_before(self.out) if start < settings.iterations else []
            if removed:
                logging.getLogger(__name__).info("removed what was made of the fit before it resumed: %s", ", ".join(removed))
        cameras = self._render_cameras()
        loop = TrainingLoop(model, self.renderer, settings, terms=initializer_terms(self.initializers, self.scene),
                            prune=initializer_pruning(self.initializers, self.scene), densifier=self.densifier, densify_state=densify_state)
        began = time.perf_counter() - elapsed

        def sample(step: int) -> Sample:
            view = self.views[schedule.next()]
            return Sample(view, cameras[view.index], model.gaussians())

        def log_block(step: Step) -> None:
            block = record.add(step.loss.item(), step.psnr())
            if block is not None:
                curve.log(step=step.number + 1, frame=settings.frame, loss=block[0], psnr=block[1], gaussians=step.gaussians,
                          elapsed_s=time.perf_counter() - began)

        def save(done: int) -> None:
            self._checkpoint(checkpoint, model, generator, schedule, record, curve, densify_state, done, time.perf_counter() - began)

        try:
            loop.run(range(start, settings.iterations), sample, record=log_block, checkpoint=save, checkpoint_every=settings.checkpoint_every,
                     desc="fit", progress=self.progress)
        except FitError as error:
            self._info(model, record, loop.step, time.perf_counter() - began, DIVERGED, str(error)).write(self.out)
            raise
        info = self._info(model, record, settings.iterations, time.perf_counter() - began, COMPLETE)
        info.write(self.out)
        return info

    # -------------------------------------------------------------------------------- checkpointing

    def _checkpoint(self, path: Path, model, generator, schedule, record: BlockLosses, curve: TrainingCurve, densify_state, step: int,
                    elapsed: float) -> None:
        state = {
            "step": step,
            "elapsed": elapsed,
            "model": model.state_dict(),
            "generator": generator.get_state(),
            "schedule": list(schedule.queue),
            "losses": attrs.asdict(record),
            "curve": curve.rows,
            "densifier": densify_state,
        }
        with signals_deferred():
            save_checkpoint(path, self._key(), state)
            curve.write(self.out)
            self._info(model, record, step, elapsed, RUNNING if step < self.settings.iterations else COMPLETE).write(self.out)

    def _key(self) -> dict[str, Any]:
        """What a checkpoint must have been written with to be resumed."""
        return {"configuration": self.config.values, "session": self.session.url, "recording": self.session.fingerprint,
                "training cameras": [c.name for c in self.train_cameras]}

    def _resume(self, path: Path, model, generator, schedule, densify_state) -> tuple[int, float, BlockLosses, list[dict]]:
        payload = resume_checkpoint(path, self._key(), "use a new --out or delete the checkpoint")
        model.load_state_dict(payload["model"])
        generator.set_state(payload["generator"])
        schedule.queue = list(payload["schedule"])
        densify_state.clear()
        densify_state.update(payload["densifier"])
        # A checkpoint of an older mmcsplat holds no curve (or PSNR sum): the curve restarts from here.
        losses = {"psnr_total": 0.0, **payload["losses"]}
        return int(payload["step"]), float(payload["elapsed"]), BlockLosses(**losses), list(payload.get("curve", []))

    def _info(self, model: GaussianModel, record: BlockLosses, step: int, elapsed: float, status: str, error: str | None = None) -> RunInfo:
        return RunInfo(
            status=status,
            error=error,
            warnings=self.warnings,
            session=self.session.url if "://" in self.session.url else str(Path(self.session.url).resolve()),
            config=self.config.source,
            config_values=with_renderer(self.config, self.renderer_choice).values,  # the renderer --backend chose, not the table's
            renderer=self.renderer_choice.name,
            frame=self.settings.frame,
            train_cameras=[c.name for c in self.train_cameras],
            heldout_cameras=[c.name for c in self.heldout_cameras],
            iterations=step,
            num_gaussians=model.count,
            wall_s=round(elapsed, 3),
            loss_min=record.lowest,
            loss_final=record.last,
            scene_center=np.asarray(self.scene.center).tolist(),
            scene_scale=self.scene.scale,
            resumed_from=self.resumed_from,
            recording=self.session.fingerprint,
        )

