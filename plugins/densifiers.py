"""Densification strategies: how the Gaussian set grows, splits, dies and moves during a fit."""

from __future__ import annotations

from typing import Any

import attrs
import torch

from mmcsplat.plugin_api.interfaces import Densifier
from mmcsplat.plugin_api.parameters import at_least, between, finite_positive, parameter
from mmcsplat.plugin_api.render_contract import RenderOutput
from mmcsplat.scene.quaternions import quat_to_rotmat
from mmcsplat.training.model import GaussianModel


def _rows(model: GaussianModel, index: torch.Tensor) -> dict[str, torch.Tensor]:
    return {name: tensor.detach()[index].clone() for name, tensor in model.params.items()}


def _set_opacity(model: GaussianModel, opacity_logits: torch.Tensor) -> None:
    with torch.no_grad():
        model.params["opacity_logits"].copy_(opacity_logits)
    state = model.optimizers["opacity_logits"].state.get(model.params["opacity_logits"])
    if state:
        state["exp_avg"].zero_()
        state["exp_avg_sq"].zero_()


@attrs.frozen
class DefaultDensifier(Densifier):
    """3DGS densification: Gaussians with a large accumulated screen-space gradient are cloned (small) or
    split in two (large); faint or huge Gaussians are pruned; opacities are reset now and then."""

    grad_threshold: float = parameter(2e-4, doc="mean screen-space gradient that densifies a Gaussian", validator=finite_positive)
    size_fraction: float = parameter(0.01, doc="larger than this × scene scale: split, else clone", validator=finite_positive)
    split_factor: float = parameter(1.6, doc="a split child's scales are its parent's divided by this", validator=finite_positive)
    prune_opacity: float = parameter(0.005, doc="opacity below which a Gaussian is pruned", validator=between(0, 1))
    prune_size_fraction: float = parameter(0.1, doc="larger than this × scene scale: pruned", validator=finite_positive)
    start: int = parameter(500, doc="first iteration that densifies", validator=at_least(0))
    stop: int = parameter(15_000, doc="last iteration that densifies", validator=at_least(0))
    every: int = parameter(100, doc="iterations between densifications", validator=at_least(1))
    reset_every: int = parameter(3000, doc="iterations between opacity resets", validator=at_least(1))
    reset_opacity: float = parameter(0.01, doc="the opacity a reset caps every Gaussian to", validator=between(0, 1))

    def initialize_state(self, scene_scale: float) -> dict[str, Any]:
        return {"scene_scale": scene_scale, "grad_sum": None, "count": None}

    def step_post_backward(self, model: GaussianModel, state: dict[str, Any], step: int, render: RenderOutput) -> None:
        if step >= self.stop:
            return
        self._accumulate(model, state, render)
        if step >= self.start and step % self.every == 0:
            self._densify_and_prune(model, state, step)
        if step > 0 and step % self.reset_every == 0:
            cap = torch.logit(torch.tensor(self.reset_opacity))
            _set_opacity(model, model.params["opacity_logits"].detach().clamp(max=cap))

    def _accumulate(self, model: GaussianModel, state: dict[str, Any], render: RenderOutput) -> None:
        grad = render.means2d.grad
        n = model.count
        if state["grad_sum"] is None or len(state["grad_sum"]) != n:  # pruned elsewhere: start afresh
            state["grad_sum"] = torch.zeros(n)
            state["count"] = torch.zeros(n)
        if grad is None or grad.shape[1] != n:
            return
        height, width = render.rgb.shape[1:3]
        # The threshold is in normalised device coordinates, as 3DGS and gsplat measure it.
        # A GPU renderer's means2d stays on its device (its .grad is only there); the statistics live with the model.
        ndc = grad.detach().to(state["grad_sum"].device) * torch.tensor([width / 2.0, height / 2.0], dtype=grad.dtype)
        visible = render.radii > 0
        for camera in range(grad.shape[0]):
            seen = visible[camera]
            state["grad_sum"][seen] += ndc[camera][seen].norm(dim=-1).float()
            state["count"][seen] += 1

    def _densify_and_prune(self, model: GaussianModel, state: dict[str, Any], step: int) -> None:
        scene_scale = state["scene_scale"]
        average = state["grad_sum"] / state["count"].clamp_min(1)
        size = model.params["log_scales"].detach().exp().amax(dim=-1)
        grown = average >= self.grad_threshold
        clone = grown & (size <= self.size_fraction * scene_scale)
        split = grown & (size > self.size_fraction * scene_scale)
        generator = torch.Generator().manual_seed(step)  # reproducible after a resume

        clone_rows = _rows(model, clone.nonzero()[:, 0])
        split_index = split.nonzero()[:, 0].repeat(2)
        split_rows = _rows(model, split_index)
        scales = split_rows["log_scales"].exp()
        offsets = torch.randn(scales.shape, generator=generator) * scales
        rotation = quat_to_rotmat(split_rows["quats"])
        split_rows["means"] = split_rows["means"] + (rotation @ offsets[..., None])[..., 0]
        split_rows["log_scales"] = torch.log(scales / self.split_factor)
        edit = {name: torch.cat([clone_rows[name], split_rows[name]]) for name in clone_rows}
        # As 3DGS, prune after densifying, over the whole set: a faint or oversized Gaussian's clone or children go too.
        fresh = ~self._faint_or_oversized(edit["opacity_logits"], edit["log_scales"], scene_scale)
        edit = {name: rows[fresh] for name, rows in edit.items()}
        doomed = split | self._faint_or_oversized(model.params["opacity_logits"].detach(), model.params["log_scales"].detach(), scene_scale)
        if edit["means"].shape[0] or doomed.any():
            model.replace(edit, keep=~doomed)
        state["grad_sum"] = torch.zeros(model.count)
        state["count"] = torch.zeros(model.count)

    def _faint_or_oversized(self, opacity_logits: torch.Tensor, log_scales: torch.Tensor, scene_scale: float) -> torch.Tensor:
        """[N] bool: opacity below ``prune_opacity`` or size above ``prune_size_fraction`` × the scene scale."""
        size = log_scales.exp().amax(dim=-1)
        return (torch.sigmoid(opacity_logits) < self.prune_opacity) | (size > self.prune_size_fraction * scene_scale)


@attrs.frozen
class BudgetDensifier(Densifier):
    """Never more than ``cap`` Gaussians — "model no more than a scene needs". Dead Gaussians are relocated
    onto live ones drawn in proportion to opacity (MCMC-style: the source and its copies share its opacity
    so the rendered image is unchanged to first order), and the set grows the same way while under the
    cap. An initialisation above the cap is cut to the most opaque ``cap``."""

    cap: int = parameter(20_000, doc="most Gaussians ever held", validator=at_least(1))
    growth: float = parameter(0.05, doc="share of N added at each step while under the cap", validator=at_least(0))
    dead_opacity: float = parameter(0.005, doc="opacity below which a Gaussian is dead and relocated", validator=between(0, 1))
    start: int = parameter(500, doc="first iteration that relocates and grows", validator=at_least(0))
    stop: int = parameter(15_000, doc="last iteration that relocates and grows", validator=at_least(0))
    every: int = parameter(100, doc="iterations between steps", validator=at_least(1))

    def initialize_state(self, scene_scale: float) -> dict[str, Any]:
        return {}

    def step_post_backward(self, model: GaussianModel, state: dict[str, Any], step: int, render: RenderOutput) -> None:
        opacity = torch.sigmoid(model.params["opacity_logits"].detach())
        if model.count > self.cap:
            keep = torch.zeros(model.count, dtype=torch.bool)
            keep[opacity.topk(self.cap).indices] = True
            model.replace({}, keep=keep)
            return
        if not (self.start <= step < self.stop and step % self.every == 0):
            return
        generator = torch.Generator().manual_seed(step)
        dead = opacity < self.dead_opacity
        alive = (~dead).nonzero()[:, 0]
        if len(alive) == 0:
            return
        grow = min(self.cap - model.count, int(self.growth * model.count))
        copies = int(dead.sum()) + max(grow, 0)
        if copies == 0:
            return
        weights = opacity[alive]
        sources = alive[torch.multinomial(weights, copies, replacement=True, generator=generator)]
        # Each source and its k copies share its opacity: 1 − (1 − o)^(1 / (k + 1)) each.
        per_source = torch.bincount(sources, minlength=model.count).float()
        shared = 1 - (1 - opacity).pow(1 / (per_source + 1))
        new_logits = torch.where(per_source > 0, torch.logit(shared.clamp(1e-6, 1 - 1e-6)), model.params["opacity_logits"].detach())
        _set_opacity(model, new_logits)
        model.replace(_rows(model, sources), keep=~dead)
