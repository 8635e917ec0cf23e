"""The training driver: the one training step every training shares — the first-frame fit, each dynamics
method, a third-party one — and the loop around it.

A step renders the sample's Gaussians in its view's camera and composes the loss: the per-view objective
(:func:`~mmcsplat.training.objective.view_loss`: image and segmentation) plus each extra :data:`LossTerm`
(priors, the initializers' extra losses, terms to come such as a flow loss); then densifier pre-hook,
backward, finite check of the gradients, the extra optimisers (e.g. a deformation field's), the model's
optimisers, densifier post-hook, pruning, finite check of the parameters. The loop around the steps
draws each step's :class:`Sample`, shows the progress bar, calls the method's record hook (curves,
running means) and its checkpoint hook, may stop early by a :class:`PlateauStop`, and keeps the CPU thread
count to the cores other processes leave free (:mod:`~mmcsplat.training.threads`).

A method says only what differs: what each step trains on (its ``sample``), which parameters are frozen
(``requires_grad``), the extra terms, pruning rules and optimisers, and what it records and checkpoints.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import attrs
import torch

from .finite import FitError, NonFiniteError, check_finite
from .objective import view_loss, view_psnr
from .threads import thread_policy

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import Densifier, Initializer, Renderer, SceneContext, TrainingView
    from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, RenderOutput

    from .model import GaussianModel
    from .settings import FitSettings

#: An extra loss term: given the step number, the step's render and its view, a scalar tensor added to
#: the loss, or ``None`` for nothing this step.
LossTerm = Callable[[int, "RenderOutput", "TrainingView"], "torch.Tensor | None"]
#: A pruning rule: given the step number and the model after its optimiser step, [N] bool of the
#: Gaussians to remove, or ``None``.
PruneRule = Callable[[int, "GaussianModel"], "torch.Tensor | None"]
#: An extra optimiser step, given the step number: called after the gradient check, before the model's own.
OptimizerStep = Callable[[int], None]

POSTFIX_EVERY = 10  # steps between updates of the progress bar's loss, PSNR and Gaussian count


@attrs.frozen(eq=False)
class Sample:
    """What one step trains on: the ``view`` (target image, masks, backdrop), the render ``cameras`` of its
    camera, and the ``gaussians`` rendered — the model's own, or derived from them (e.g. deformed to the
    view's time) so that gradients reach the model."""

    view: TrainingView
    cameras: RenderCameras
    gaussians: Gaussians


@attrs.define(eq=False)
class Step:
    """One finished step: its ``number``, ``view``, ``render``, the composed ``loss`` (detached), the
    colour-corrected rendered ``image`` and the model's Gaussian count after it. :meth:`psnr` is computed
    on first use."""

    number: int
    view: TrainingView
    render: RenderOutput
    loss: torch.Tensor
    image: torch.Tensor
    gaussians: int
    _psnr: float | None = attrs.field(default=None, init=False)

    def psnr(self) -> float:
        """PSNR (dB) of the rendered image against the view's target."""
        if self._psnr is None:
            self._psnr = view_psnr(self.image, self.view)
        return self._psnr


@attrs.define
class PlateauStop:
    """A stopping rule: stop when the loss stops improving. Losses are averaged over blocks of ``window``
    steps (single steps differ by the camera they see more than by the training); a block mean below the
    lowest so far by more than ``tolerance`` (relative) is an improvement, and ``patience`` blocks in a
    row without one stop the loop. The loop's range stays the cap. Its state restarts with each
    :meth:`TrainingLoop.run` (one frame's training)."""

    window: int = attrs.field(validator=attrs.validators.ge(1))
    patience: int = attrs.field(default=1, validator=attrs.validators.ge(1))
    tolerance: float = attrs.field(default=0.0, validator=attrs.validators.ge(0))
    _total: float = attrs.field(default=0.0, init=False)
    _count: int = attrs.field(default=0, init=False)
    _lowest: float | None = attrs.field(default=None, init=False)
    _stale: int = attrs.field(default=0, init=False)

    def reset(self) -> None:
        """Forget every loss seen (a new frame's training starts)."""
        self._total, self._count, self._lowest, self._stale = 0.0, 0, None, 0

    def update(self, loss: float) -> bool:
        """Count one step's loss; ``True`` when training should stop after this step."""
        self._total += loss
        self._count += 1
        if self._count < self.window:
            return False
        mean = self._total / self.window
        self._total, self._count = 0.0, 0
        if self._lowest is None or mean < self._lowest * (1 - self.tolerance):
            self._lowest, self._stale = mean, 0
            return False
        self._lowest = min(self._lowest, mean)
        self._stale += 1
        return self._stale >= self.patience


def initializer_terms(initializers: Sequence[Initializer], scene: SceneContext) -> list[LossTerm]:
    """The initializers' ``extra_loss`` hooks as loss terms of a training on ``scene``."""
    return [lambda step, render, view, initializer=initializer: initializer.extra_loss(step, render, view.camera, scene)
            for initializer in initializers]


def initializer_pruning(initializers: Sequence[Initializer], scene: SceneContext) -> list[PruneRule]:
    """The initializers' ``prune_mask`` hooks as pruning rules of a training on ``scene``."""
    return [lambda step, model, initializer=initializer: initializer.prune_mask(step, model.gaussians(), scene)
            for initializer in initializers]


class TrainingLoop:
    """The training step and loop over one :class:`GaussianModel` (module docstring).

    ``renderer`` renders each sample; ``settings`` weigh the per-view objective, ``lambda_seg`` overriding
    their segmentation weight; ``terms`` are added to it in order; ``prune`` rules remove Gaussians after
    the optimiser step (all of them removed is a :class:`FitError`); ``densifier`` with its
    ``densify_state`` grows and culls the model; ``optimizers`` are extra optimiser steps (parameters
    outside the model). :attr:`step` is the number of the step running (or last run)."""

    def __init__(
        self,
        model: GaussianModel,
        renderer: Renderer,
        settings: FitSettings,
        *,
        lambda_seg: float | None = None,
        terms: Sequence[LossTerm] = (),
        prune: Sequence[PruneRule] = (),
        densifier: Densifier | None = None,
        densify_state: dict[str, Any] | None = None,
        optimizers: Sequence[OptimizerStep] = (),
    ) -> None:
        self.model = model
        self.renderer = renderer
        self.settings = settings
        self.lambda_seg = lambda_seg
        self.terms = list(terms)
        self.prune = list(prune)
        self.densifier = densifier
        self.densify_state = {} if densify_state is None else densify_state
        self.optimizers = list(optimizers)
        self.step = 0

    def train_step(self, number: int, sample: Sample) -> Step:
        """One step on ``sample`` (module docstring); a :class:`NonFiniteError` at the first NaN or infinity."""
        model, densifier = self.model, self.densifier
        self.step = number
        render = self.renderer.render(sample.gaussians, sample.cameras)
        loss, image = view_loss(model, sample.view, render, self.settings, self.lambda_seg)
        for term in self.terms:
            extra = term(number, render, sample.view)
            if extra is not None:
                loss = loss + extra
        if densifier:
            densifier.step_pre_backward(model, self.densify_state, number, render)
        loss.backward()
        check_finite(loss, model, number, "gradient")
        for optimizer_step in self.optimizers:
            optimizer_step(number)
        model.step()
        if densifier:
            densifier.step_post_backward(model, self.densify_state, number, render)
        self._prune(number)
        check_finite(loss, model, number, "parameter")
        return Step(number, sample.view, render, loss.detach(), image, model.count)

    def _prune(self, number: int) -> None:
        remove = None
        for rule in self.prune:
            mask = rule(number, self.model)
            if mask is not None:
                remove = mask if remove is None else remove | mask
        if remove is not None and remove.any():
            if remove.all():
                raise FitError(f"every Gaussian was pruned at iteration {number}: check the initializers' radius and the learning rates")
            self.model.replace({}, keep=~remove)

    def run(
        self,
        steps: range,
        sample: Callable[[int], Sample],
        *,
        record: Callable[[Step], None] | None = None,
        checkpoint: Callable[[int], None] | None = None,
        checkpoint_every: int = 0,
        stop: PlateauStop | None = None,
        where: str | None = None,
        desc: str = "train",
        progress: bool = True,
        leave: bool = True,
    ) -> int:
        """Train ``steps`` (the cap; a resumed training starts past 0), each on ``sample(number)``; returns
        how many steps were done in all (``steps.stop`` unless ``stop`` ended the loop earlier).

        After each step ``record`` sees it (curves, running means); ``checkpoint(done)`` runs every
        ``checkpoint_every`` steps done and after the last. ``where`` (e.g. ``"frame 12"``) prefixes a
        non-finite error's message. The progress bar (``desc``; ``leave`` it when done) counts from
        ``steps.start`` to ``steps.stop``."""
        from tqdm import tqdm

        if stop is not None:
            stop.reset()
        threads = thread_policy()
        done = steps.start
        bar = tqdm(steps, initial=steps.start, total=steps.stop, desc=desc, unit="it", leave=leave, disable=not progress)
        try:
            for number in bar:
                threads.update()
                try:
                    step = self.train_step(number, sample(number))
                except NonFiniteError as error:
                    if where is None:
                        raise
                    raise NonFiniteError(f"{where}: {error}") from error
                done = number + 1
                if record is not None:
                    record(step)
                if number % POSTFIX_EVERY == 0:
                    bar.set_postfix(loss=f"{step.loss.item():.4f}", psnr=f"{step.psnr():.2f}", n=step.gaussians)
                stopping = stop is not None and stop.update(step.loss.item())
                if checkpoint is not None and (stopping or done == steps.stop or (checkpoint_every and done % checkpoint_every == 0)):
                    checkpoint(done)
                if stopping:
                    break
        finally:
            bar.close()
        return done
