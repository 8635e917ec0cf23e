"""The first-frame fit: Gaussians optimised against the training cameras of one frame.

Every choice comes from the configuration through the registry: the renderer, the composed initializers,
the densifier. The run directory holds an atomic checkpoint (a killed run resumes from it), ``run.json``
(what was fitted, how long it took, how it ended, the loss record of :class:`BlockLosses`, warnings)
and the final Gaussians.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
import torch

from . import losses
from .atomic import atomic_path, write_json_atomic
from .backdrop import Background, camera_backdrop, composite, parse_background
from .camera import Camera
from .config import Config
from .errors import MmcsplatError
from .geometry import rig_center, rig_scale
from .interfaces import Densifier, Initializer, Renderer, SceneContext
from .model import GAUSSIAN_PARAMETERS, GaussianModel, LearningRates
from .registry import Registry, default_registry
from .rendering import RenderCameras, RenderOutput
from .store import SessionReader
from .supersampling import supersampled

CHECKPOINT = "checkpoint.pt"
RUN_INFO = "run.json"
#: Fewer training cameras seeing the subject than this under-constrain a frame: the fit warns. On the
#: synthetic capture (64 × 48, visual-hull start, 1000 iterations) 4 training cameras left no opacity
#: outside the masks' visual hull and 3 left 10–16 % of it there (docs/studies.md, "Stability").
MIN_TRAINING_CAMERAS = 4


class FitError(MmcsplatError):
    """A fit that cannot go on (diverged, or every Gaussian pruned away)."""


class NonFiniteError(FitError):
    """A loss, gradient or parameter became NaN or infinite."""


def _whole_factor(instance: Any, attribute: attrs.Attribute, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"fit.{attribute.name} must be a whole number ≥ 1 (sub-pixels per pixel side), got {value!r}")


@attrs.frozen
class FitSettings:
    """The ``[fit]`` table of a configuration."""

    iterations: int = 2000
    frame: int = 0
    seed: int = 0
    lambda_image: float = 1.0
    lambda_seg: float = 3.0
    ssim_weight: float = 0.2
    checkpoint_every: int = 500
    #: Render at N× and average N × N sub-pixels into each pixel, as a camera's pixel integrates over its
    #: area (:mod:`mmcsplat.supersampling`); evaluation, tracking and renders of the run do the same.
    supersample: int = attrs.field(default=1, validator=_whole_factor)
    #: An RGB colour, or "plate": each camera's clean plate (:mod:`mmcsplat.backdrop`).
    background: Background = attrs.field(default=(0.0, 0.0, 0.0), converter=parse_background)
    lrs: LearningRates = attrs.field(factory=LearningRates, converter=lambda v: v if isinstance(v, LearningRates) else LearningRates(**v))

    @classmethod
    def from_config(cls, config: Config) -> FitSettings:
        table = dict(config.get("fit", {}))
        known = {field.name for field in attrs.fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ValueError(f"{config.source}: unknown [fit] keys {unknown}; known: {sorted(known)}")
        return cls(**table)


@attrs.frozen(eq=False)
class TrainingView:
    """One training camera's data of one frame as tensors."""

    camera: Camera
    index: int
    image: torch.Tensor  # [H, W, 3] float, the loss target (after initializers' prepare_target)
    mask: torch.Tensor | None  # [H, W] bool
    seg_target: torch.Tensor | None  # [H, W, 1] float
    backdrop: torch.Tensor  # [3] or [H, W, 3]: what renders of this camera are composited over

    def composite(self, render: RenderOutput) -> torch.Tensor:
        """``render`` — of this view's camera alone, over black — over this view's backdrop."""
        return composite(render, 0, self.backdrop)


def load_view(
    session: SessionReader, t: int, camera: Camera, index: int, initializers: Sequence[Initializer], backdrop: torch.Tensor
) -> TrainingView:
    """Frame ``t`` of ``camera`` (training camera number ``index``) as loss targets, shaped by the
    initializers' ``prepare_target``. They shape the image's difference from the ``backdrop``, so masking
    (which zeroes the outside of the subject) leaves the backdrop there: black, or the clean plate."""
    data = session.frame(t, camera.name)
    image = torch.from_numpy(data.rgb.astype(np.float32) / 255.0)
    mask = torch.from_numpy(data.mask.copy()) if data.mask is not None else None
    subject = image - backdrop
    for initializer in initializers:
        subject = initializer.prepare_target(subject, mask)
    seg = mask[..., None].float() if mask is not None else None
    return TrainingView(camera, index, subject + backdrop, mask, seg, backdrop)


class CameraSchedule:
    """Cameras in random order without replacement, one block (a permutation) at a time."""

    def __init__(self, count: int, generator: torch.Generator) -> None:
        self.count = count
        self.generator = generator
        self.queue: list[int] = []

    def next(self) -> int:
        if not self.queue:
            self.queue = torch.randperm(self.count, generator=self.generator).tolist()
        return self.queue.pop()


@attrs.define
class BlockLosses:
    """The loss averaged over each block of ``size`` iterations — one block of the camera schedule, every
    training camera once — whose lowest (``lowest``) and latest (``last``) complete means run.json
    records as ``loss_min`` and ``loss_final``. Single iterations each see another camera, so their
    losses differ by the camera more than by the training; block means compare. A blow-up is a final
    mean far above the lowest. Saved in the checkpoint, so a resumed fit records the same."""

    size: int
    total: float = 0.0
    count: int = 0
    lowest: float | None = None
    last: float | None = None

    def add(self, loss: float) -> None:
        """Count one iteration's loss; the block's mean is taken when it is complete."""
        self.total += loss
        self.count += 1
        if self.count == self.size:
            self.last = self.total / self.size
            self.lowest = self.last if self.lowest is None else min(self.lowest, self.last)
            self.total, self.count = 0.0, 0


def select_cameras(session: SessionReader, holdout: Sequence[str] | None) -> tuple[list[Camera], list[Camera]]:
    """(training cameras, held-out cameras): ``holdout`` overrides the session's own held-out list."""
    held = list(session.heldout if holdout is None else holdout)
    unknown = [name for name in held if name not in session.camera_names]
    if unknown:
        raise ValueError(f"held-out camera(s) {unknown} not in session {session.source!r}; cameras: {list(session.camera_names)}")
    train = [session.camera(name) for name in session.camera_names if name not in held]
    if len(train) < 2:
        raise ValueError(f"a fit needs at least two training cameras; session has {list(session.camera_names)}, held out {held}")
    return train, [session.camera(name) for name in held]


class FirstFrameFit:
    """One first-frame fit, configured by a :class:`Config`; ``run()`` trains (resuming if possible)."""

    def __init__(
        self,
        session: SessionReader,
        config: Config,
        out: Path,
        holdout: Sequence[str] | None = None,
        backend: str | None = None,
        registry: Registry | None = None,
        progress: bool = True,
    ) -> None:
        self.session = session
        self.config = config
        self.out = Path(out)
        self.settings = FitSettings.from_config(config)
        self.registry = registry or default_registry()
        self.progress = progress
        self.renderer_name = backend or config.plugin("renderer").name
        renderer_params = dict(config.plugin("renderer").params) if not backend else {}
        self.renderer: Renderer = supersampled(self.registry.create("renderer", self.renderer_name, **renderer_params), self.settings.supersample)
        self.initializers: list[Initializer] = [choice.build(self.registry) for choice in config.plugins("initializer")]
        densifiers = config.plugins("densifier")
        self.densifier: Densifier | None = densifiers[0].build(self.registry) if densifiers else None
        self.train_cameras, self.heldout_cameras = select_cameras(session, holdout)
        center = rig_center(session.cameras)
        self.scene = SceneContext(session, tuple(self.train_cameras), self.settings.frame, center, rig_scale(session.cameras, center))
        self.views = self._load_views()

    def _load_views(self) -> list[TrainingView]:
        frame = self.settings.frame
        views = [
            load_view(self.session, frame, camera, index, self.initializers, camera_backdrop(self.settings.background, self.session, camera.name))
            for index, camera in enumerate(self.train_cameras)
        ]
        if self.settings.lambda_seg > 0 and any(view.seg_target is None for view in views):
            missing = [view.camera.name for view in views if view.seg_target is None]
            raise ValueError(
                f"fit.lambda_seg = {self.settings.lambda_seg} needs subject masks, but session {self.session.source!r} "
                f"has none for camera(s) {missing} at frame {frame}: run `mmcsplat segment` or set fit.lambda_seg=0"
            )
        masked = [view for view in views if view.mask is not None]
        if masked and not any(bool(view.mask.any()) for view in masked):
            raise ValueError(f"the subject mask is empty in every training view of frame {frame}: check the segmentation")
        self.warnings = [f"camera {view.camera.name!r} never sees the subject at frame {frame} (empty mask)" for view in masked if not view.mask.any()]
        seeing = sum(view.mask is None or bool(view.mask.any()) for view in views)
        if seeing < MIN_TRAINING_CAMERAS:
            self.warnings.insert(0, f"only {seeing} training cameras see the subject at frame {frame}: it is under-constrained "
                                    f"(expect floaters; at least {MIN_TRAINING_CAMERAS} are advised)")
        for warning in self.warnings:
            warnings.warn(warning, stacklevel=2)
        return views

    # ------------------------------------------------------------------------------------------ setup

    def _initial_model(self, generator: torch.Generator) -> GaussianModel:
        for initializer in self.initializers:
            gaussians = initializer.initial_gaussians(self.scene, generator)
            if gaussians is not None:
                break
        else:
            raise ValueError(f"{self.config.source}: no [[initializer]] places initial Gaussians (e.g. 'random' or 'visual-hull')")
        if gaussians.count == 0:
            raise ValueError(f"{self.config.source}: the initializers placed no Gaussians")
        return GaussianModel(gaussians, tuple(c.name for c in self.train_cameras), self.settings.lrs, self.scene.scale)

    def _render_cameras(self) -> RenderCameras:
        return RenderCameras.from_cameras(self.train_cameras)

    # -------------------------------------------------------------------------------------- training

    def run(self) -> dict[str, Any]:
        """Train to ``settings.iterations`` (resuming from a checkpoint in ``out``); returns run.json."""
        from tqdm import tqdm

        self.out.mkdir(parents=True, exist_ok=True)
        settings = self.settings
        generator = torch.Generator().manual_seed(settings.seed)
        model = self._initial_model(generator)
        schedule = CameraSchedule(len(self.views), generator)
        record = BlockLosses(len(self.views))
        densify_state = self.densifier.initialize_state(self.scene.scale) if self.densifier else {}
        start, elapsed = 0, 0.0
        checkpoint = self.out / CHECKPOINT
        if checkpoint.exists():
            start, elapsed, record = self._resume(checkpoint, model, generator, schedule, densify_state)
        cameras = self._render_cameras()
        bar = tqdm(range(start, settings.iterations), initial=start, total=settings.iterations, desc="fit", disable=not self.progress, unit="it")
        began = time.perf_counter() - elapsed
        try:
            for step in bar:
                index = schedule.next()
                view = self.views[index]
                render = self.renderer.render(model.gaussians(), cameras.select([index]))
                image = model.correct_color(view.composite(render), index)
                loss = settings.lambda_image * losses.photometric_loss(image, view.image, settings.ssim_weight)
                if settings.lambda_seg > 0:
                    loss = loss + settings.lambda_seg * losses.photometric_loss(render.features[0, ..., :1], view.seg_target, settings.ssim_weight)
                for initializer in self.initializers:
                    extra = initializer.extra_loss(step, render, view.camera, self.scene)
                    if extra is not None:
                        loss = loss + extra
                if self.densifier:
                    self.densifier.step_pre_backward(model, densify_state, step, render)
                loss.backward()
                self._check_finite(loss, model, step, "gradient")
                model.step()
                if self.densifier:
                    self.densifier.step_post_backward(model, densify_state, step, render)
                self._prune(model, step)
                self._check_finite(loss, model, step, "parameter")
                record.add(loss.item())
                if step % 10 == 0:
                    bar.set_postfix(loss=f"{loss.item():.4f}", psnr=f"{float(losses.psnr(image.detach().clamp(0, 1), view.image)):.2f}", n=model.count)
                done = step + 1
                if done % settings.checkpoint_every == 0 or done == settings.iterations:
                    self._checkpoint(checkpoint, model, generator, schedule, record, densify_state, done, time.perf_counter() - began)
        except FitError as error:
            info = self._info(model, record, step, time.perf_counter() - began, "diverged", str(error))
            write_json_atomic(self.out / RUN_INFO, info)
            raise
        finally:
            bar.close()
        info = self._info(model, record, settings.iterations, time.perf_counter() - began, "complete")
        write_json_atomic(self.out / RUN_INFO, info)
        return info

    def _prune(self, model: GaussianModel, step: int) -> None:
        remove = None
        for initializer in self.initializers:
            mask = initializer.prune_mask(step, model.gaussians(), self.scene)
            if mask is not None:
                remove = mask if remove is None else remove | mask
        if remove is not None and remove.any():
            if remove.all():
                raise FitError(f"every Gaussian was pruned at iteration {step}: check the initializers' radius and the learning rates")
            model.replace({}, keep=~remove, source=None)

    @staticmethod
    def _check_finite(loss: torch.Tensor, model: GaussianModel, step: int, what: str) -> None:
        """Stop at the first NaN/Inf, naming where it appeared: the loss, a gradient or a parameter."""
        if not torch.isfinite(loss):
            raise NonFiniteError(f"the loss became {loss.item()} at iteration {step}")
        for name in GAUSSIAN_PARAMETERS:
            value = model.params[name] if what == "parameter" else model.params[name].grad
            if value is not None and not torch.isfinite(value).all():
                bad = int((~torch.isfinite(value)).reshape(len(value), -1).any(dim=1).sum())
                raise NonFiniteError(f"{what} of {name!r} became non-finite in {bad} Gaussian(s) at iteration {step}")

    # -------------------------------------------------------------------------------- checkpointing

    def _checkpoint(self, path: Path, model, generator, schedule, record: BlockLosses, densify_state, step: int, elapsed: float) -> None:
        payload = {
            "step": step,
            "elapsed": elapsed,
            "model": model.state_dict(),
            "generator": generator.get_state(),
            "schedule": list(schedule.queue),
            "losses": attrs.asdict(record),
            "densifier": densify_state,
            "config": self.config.values,
        }
        with atomic_path(path) as temporary:
            torch.save(payload, temporary)
        write_json_atomic(self.out / RUN_INFO, self._info(model, record, step, elapsed, "running" if step < self.settings.iterations else "complete"))

    def _resume(self, path: Path, model, generator, schedule, densify_state) -> tuple[int, float, BlockLosses]:
        payload = torch.load(path, weights_only=False)
        if payload["config"] != self.config.values:
            raise ValueError(f"{path} was written by a different configuration; use a new --out or delete the checkpoint")
        model.load_state_dict(payload["model"])
        generator.set_state(payload["generator"])
        schedule.queue = list(payload["schedule"])
        densify_state.clear()
        densify_state.update(payload["densifier"])
        # A checkpoint written before losses were recorded: the record starts at the resumed iteration.
        record = BlockLosses(**payload["losses"]) if "losses" in payload else BlockLosses(len(self.views))
        return int(payload["step"]), float(payload["elapsed"]), record

    def _info(self, model: GaussianModel, record: BlockLosses, step: int, elapsed: float, status: str, error: str | None = None) -> dict[str, Any]:
        return {
            "status": status,
            "error": error,
            "warnings": self.warnings,
            "session": self.session.url if "://" in self.session.url else str(Path(self.session.url).resolve()),
            "config": self.config.source,
            "config_values": self.config.values,
            "renderer": self.renderer_name,
            "frame": self.settings.frame,
            "train_cameras": [c.name for c in self.train_cameras],
            "heldout_cameras": [c.name for c in self.heldout_cameras],
            "iterations": step,
            "num_gaussians": model.count,
            "wall_s": round(elapsed, 3),
            "loss_min": record.lowest,
            "loss_final": record.last,
            "scene_center": np.asarray(self.scene.center).tolist(),
            "scene_scale": self.scene.scale,
        }


def load_fitted(out: Path) -> tuple[dict[str, Any], dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    """(run.json, final parameters, camera colour scale, offset) of a completed run directory."""
    out = Path(out)
    info_path, checkpoint = out / RUN_INFO, out / CHECKPOINT
    if not info_path.exists() or not checkpoint.exists():
        raise FileNotFoundError(f"{out} is not a fit run directory (needs {RUN_INFO} and {CHECKPOINT})")
    info = json.loads(info_path.read_text())
    payload = torch.load(checkpoint, weights_only=False)
    model = payload["model"]
    return info, model["params"], model["camera_scale"], model["camera_offset"]


def fitted_background(info: Mapping[str, Any]) -> Background:
    """The ``fit.background`` a run was fitted with, from its run.json ``info``."""
    return parse_background(info.get("config_values", {}).get("fit", {}).get("background", (0.0, 0.0, 0.0)))
