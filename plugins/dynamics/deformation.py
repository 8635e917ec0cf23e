"""``deformation``: one deformation field over the whole sequence (Yang et al. 2023, the reference study's
second method). Canonical Gaussians (starting as the first-frame fit) are moved, turned and rescaled at
time t by an MLP over sinusoidal encodings of (x, y, z, t); canonical parameters and the MLP train together
on images drawn at random (t, camera) from the session, one per iteration, through the session's bounded
frame cache, so memory does not grow with the length of the sequence.

Conventions (docs/deformation.md): time is normalised to [0, 1] over the sequence's frame times; the time
noise is Gaussian with ``time_noise`` frame intervals of standard deviation (Yang et al.: 0.1 × 1/T),
annealed linearly to zero at ``noise_until`` iterations — 20 000 of the study's 40 000, scaled by
``iterations / 40 000`` for shorter runs so the last half always trains without noise; the MLP's learning
rate decays exponentially from ``lr`` to ``lr_final``; densification continues in canonical space with the
configured densifier (default: ``default``, no opacity reset, densifying until half-way).

Each iteration is the fit's training step (:class:`~mmcsplat.training.loop.TrainingLoop`) on the deformed
Gaussians, with the MLP's optimiser as an extra one. It leaves out the initializers' extra losses and
pruning: they are defined on the first frame's scene (its depth maps, and a region tested against
positions that here move with time), and the densifier prunes the canonical set.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs
import numpy as np
import torch

from mmcsplat.plugin_api.interfaces import Densifier, Dynamics, TrackingContext
from mmcsplat.plugin_api.parameters import above, at_least, parameter
from mmcsplat.plugin_api.render_contract import RenderCameras, gaussians_from_params
from mmcsplat.storage.run import DEFORMATION_CHECKPOINT
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackWriter
from mmcsplat.training.checkpoint import resume_checkpoint, save_checkpoint
from mmcsplat.training.loop import Sample, Step, TrainingLoop
from mmcsplat.training.model import GaussianModel
from mmcsplat.training.views import load_view, require_masks

from .deformation_field import DeformationField

#: The study's sequence length and the iteration by which its time noise had faded.
REFERENCE_ITERATIONS = 40_000
#: The run's training state, kept after the run (the field can be evaluated at any time later).
CHECKPOINT = DEFORMATION_CHECKPOINT
#: Deformed parameters; the others are static over the sequence.
DEFORMED = ("means", "quats", "log_scales")
STATIC = ("opacity_logits", "color_logits", "seg_logits")
CURVE_EVERY = 100  # iterations between the rows this method logs to RUN/curves.csv


@attrs.frozen
class DeformationDynamics(Dynamics):
    """A deformation field over space and time trained with the canonical Gaussians on random (frame,
    camera) images of the whole sequence; writes every frame's deformed means, quaternions and log-scales
    (module docstring; docs/deformation.md)."""

    iterations: int = parameter(2000, doc="training steps over the whole sequence, one (frame, camera) image each", validator=at_least(1))
    depth: int = parameter(4, doc="hidden layers of the MLP", validator=at_least(1))
    width: int = parameter(128, doc="units per hidden layer", validator=at_least(1))
    skip: bool = parameter(True, doc="feed the encoded input again half-way (Yang et al.)")
    frequencies: int = parameter(10, doc="sinusoidal encoding bands of (x, y, z, t)", validator=at_least(0))
    lr: float = parameter(8e-4, doc="the MLP's initial learning rate", validator=above(0))
    lr_final: float = parameter(8e-6, doc="the MLP's learning rate at the last iteration (exponential decay)", validator=above(0))
    time_noise: float = parameter(0.1, doc="time noise, standard deviation in frame intervals", validator=at_least(0))
    noise_until: int = parameter(20_000, doc="iteration by which the noise has faded (of the study's 40 000; scaled)", validator=at_least(0))
    cache_bytes: int | None = parameter(None, doc="bound on decoded frames held (none: the session's default)", validator=at_least(0))
    seed: int = parameter(0, doc="seed of the field's weights and of the image draws")
    checkpoint_every: int = parameter(500, doc="iterations between atomic checkpoints", validator=at_least(1))
    densifier: Mapping[str, Any] = parameter(doc="the densifier's table (name and parameters) over densifier_params' defaults",
                                             factory=dict, converter=dict)

    def track(self, context: TrackingContext, out: Path) -> dict[str, Any]:
        """Train the field and the canonical Gaussians (resuming from ``out/deformation.pt`` unless
        overwriting), then write every frame's state; returns the run's size, timings and cache use."""
        session = context.session if self.cache_bytes is None else SessionReader(context.session.url, cache_bytes=self.cache_bytes)
        run = _Run(self, context, session, Path(out))
        run.train()
        run.write_tracks()
        return run.summary()

    def noise_std(self, step: int, frames: int) -> float:
        """Standard deviation of the time noise at ``step``, in normalised time (``frames`` frames span 1)."""
        until = self.noise_until * min(1.0, self.iterations / REFERENCE_ITERATIONS)
        return self.time_noise / max(frames - 1, 1) * max(0.0, 1.0 - step / max(until, 1.0))

    def mlp_lr(self, step: int) -> float:
        """The MLP's learning rate at ``step``: exponential decay from ``lr`` to ``lr_final``."""
        fraction = min(step / self.iterations, 1.0)
        return math.exp((1 - fraction) * math.log(self.lr) + fraction * math.log(self.lr_final))

    def densifier_params(self) -> dict[str, Any]:
        """The densifier's table (``name`` and parameters): ``densifier`` over, when it names ``default`` or
        nothing, ``default`` every 100 iterations from 500 to half-way without opacity resets (a reset
        would undo the first-frame fit mid-sequence)."""
        table = dict(self.densifier)
        if table.get("name", "default") != "default":
            return table
        defaults = {"name": "default", "start": 500, "stop": self.iterations // 2, "every": 100, "reset_every": self.iterations + 1}
        return defaults | table


def normalised_times(session: SessionReader, frames: range) -> torch.Tensor:
    """[len(frames)] times of ``frames`` mapped onto [0, 1] (0 for a single frame)."""
    seconds = np.asarray(session.frame_times, dtype=np.float64)[frames.start : frames.stop]
    span = seconds[-1] - seconds[0]
    return torch.as_tensor((seconds - seconds[0]) / span if span > 0 else np.zeros_like(seconds), dtype=torch.float32)


class _Run:
    """One training run of :class:`DeformationDynamics`: model, field, optimiser, sampling and checkpoints."""

    def __init__(self, settings: DeformationDynamics, context: TrackingContext, session: SessionReader, out: Path) -> None:
        self.settings = settings
        self.context = context
        self.session = session
        self.out = out
        self.model = GaussianModel.from_params(context.params, tuple(c.name for c in context.cameras), context.settings.lrs,
                                               context.scene_scale, context.camera_scale, context.camera_offset)
        with torch.random.fork_rng():  # the field's initial weights, without touching the global generator
            torch.manual_seed(settings.seed)
            self.field = DeformationField(settings.depth, settings.width, settings.frequencies, settings.skip)
        self.optimizer = torch.optim.Adam(self.field.parameters(), lr=settings.lr, eps=1e-15)
        table = settings.densifier_params()
        self.densifier: Densifier = context.plugins.create("densifier", table.pop("name"), **table)
        self.densify_state = self.densifier.initialize_state(context.scene_scale)
        self.generator = torch.Generator().manual_seed(settings.seed)
        self.times = normalised_times(session, context.frames)
        # Every (frame, training camera) the session holds; images are drawn from these uniformly.
        present = np.stack([session.present(c.name)[context.frames.start : context.frames.stop] for c in context.cameras])
        self.pairs = torch.as_tensor(np.argwhere(present.T))  # [P, 2]: (tracks frame k, camera index)
        self.cameras = RenderCameras.each(context.cameras)
        self.step = 0
        self.resumed_from: int | None = None
        self.elapsed = 0.0
        self.recent: list[tuple[float, float]] = []

    # ------------------------------------------------------------------------------------- the field

    def deformed(self, k: int | torch.Tensor, noise: float = 0.0) -> dict[str, torch.Tensor]:
        """Every Gaussian parameter at tracks frame ``k`` (its normalised time plus ``noise``)."""
        params = self.model.params
        d_means, d_quats, d_scales = self.field(params["means"], self.times[k] + noise)
        deformed = {"means": params["means"] + d_means, "quats": params["quats"] + d_quats, "log_scales": params["log_scales"] + d_scales}
        return {**params, **deformed}

    # -------------------------------------------------------------------------------------- training

    def train(self) -> None:
        """Run to ``settings.iterations``, checkpointing atomically every ``checkpoint_every``."""
        settings, context = self.settings, self.context
        checkpoint = self.out / CHECKPOINT
        if checkpoint.exists() and not context.overwrite:
            self._resume(checkpoint)
        loop = TrainingLoop(self.model, context.renderer, context.settings, densifier=self.densifier, densify_state=self.densify_state,
                            optimizers=[self._step_field])
        began = time.perf_counter() - self.elapsed

        def record(step: Step) -> None:
            if step.number % 10 == 0 or step.number >= settings.iterations - 100:
                self.recent = [*self.recent[-99:], (step.loss.item(), step.psnr())]
            self.step = step.number + 1
            self.elapsed = time.perf_counter() - began
            if self.step % CURVE_EVERY == 0:  # the mean of the last 10 logged iterations, over random frames and cameras
                loss_mean, psnr_mean = np.mean(self.recent[-10:], axis=0).tolist()
                context.curve.log(step=self.step, frame=None, loss=loss_mean, psnr=psnr_mean, gaussians=step.gaussians, elapsed_s=self.elapsed)

        loop.run(range(self.step, settings.iterations), self._sample, record=record, checkpoint=lambda done: self._checkpoint(checkpoint),
                 checkpoint_every=settings.checkpoint_every, desc="deformation", progress=context.progress)

    def _sample(self, step: int) -> Sample:
        """A random (frame, camera) image of the sequence and the Gaussians deformed to its (noised) time."""
        context = self.context
        k, index = self.pairs[int(torch.randint(len(self.pairs), (1,), generator=self.generator))].tolist()
        view = load_view(self.session, context.frames[k], context.cameras[index], index, context.initializers, context.backdrops[index])
        require_masks([view], context.settings, self.session, context.frames[k])
        noise = float(torch.randn((), generator=self.generator)) * self.settings.noise_std(step, len(context.frames))
        return Sample(view, self.cameras[index], gaussians_from_params(self.deformed(k, noise)))

    def _step_field(self, step: int) -> None:
        """The MLP's optimiser step at its decayed learning rate."""
        for group in self.optimizer.param_groups:
            group["lr"] = self.settings.mlp_lr(step)
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def _key(self) -> dict[str, Any]:
        """What a checkpoint must have been written with to be resumed."""
        settings = attrs.asdict(self.settings, filter=lambda field, _: field.name not in ("checkpoint_every", "cache_bytes"))
        return {"settings": settings, "frames": [self.context.frames.start, self.context.frames.stop],
                "cameras": [c.name for c in self.context.cameras], "recording": self.context.session.fingerprint}

    def _checkpoint(self, path: Path) -> None:
        save_checkpoint(path, self._key(), {
            "step": self.step, "elapsed": self.elapsed, "recent": self.recent, "curve": self.context.curve.rows,
            "model": self.model.state_dict(), "field": self.field.state_dict(), "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(), "densifier": self.densify_state,
        })

    def _resume(self, path: Path) -> None:
        payload = resume_checkpoint(path, self._key(), "use --overwrite to start afresh")
        self.model.load_state_dict(payload["model"])
        self.field.load_state_dict(payload["field"])
        self.optimizer.load_state_dict(payload["optimizer"])
        self.generator.set_state(payload["generator"])
        self.densify_state.clear()
        self.densify_state.update(payload["densifier"])
        self.step, self.elapsed, self.recent = int(payload["step"]), float(payload["elapsed"]), list(payload["recent"])
        self.context.curve.rows[:] = payload.get("curve", [])
        self.resumed_from = self.step

    # --------------------------------------------------------------------------------------- output

    def write_tracks(self) -> None:
        """Every frame's deformed means, quaternions and log-scales; the other parameters are static."""
        from tqdm import tqdm

        static = {name: self.model.params[name].detach() for name in STATIC}
        attributes = {"first_frame": self.context.frames.start, "depth": self.settings.depth, "width": self.settings.width,
                      "iterations": self.settings.iterations, "checkpoint": CHECKPOINT}
        with TrackWriter(self.out, num_frames=len(self.context.frames), static=static, method="deformation",
                         attrs=attributes, overwrite=self.context.overwrite) as writer, torch.no_grad():
            for k in tqdm(range(len(self.context.frames)), desc="write tracks", unit="frame", disable=not self.context.progress):
                state = self.deformed(k)
                writer.write_frame(k, **{name: state[name] for name in DEFORMED})

    def summary(self) -> dict[str, Any]:
        """The run's size, time per iteration, last losses and frame-cache use (for RUN/track.json)."""
        recent = np.array(self.recent).reshape(-1, 2)
        cache = self.session.cache
        return {
            "iterations": self.step,
            "resumed_from": self.resumed_from,
            "depth": self.settings.depth,
            "width": self.settings.width,
            "field_parameters": sum(p.numel() for p in self.field.parameters()),
            "num_gaussians": self.model.count,
            "train_wall_s": round(self.elapsed, 3),
            "s_per_iteration": round(self.elapsed / max(self.step, 1), 4),
            "last_loss": float(recent[:, 0].mean()) if len(recent) else None,
            "last_psnr": float(recent[:, 1].mean()) if len(recent) else None,
            "cache_bytes": cache.max_bytes,
            "cache_hits": cache.hits,
            "cache_misses": cache.misses,
        }
