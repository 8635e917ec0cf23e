"""The trainable Gaussian scene: unconstrained parameters, their optimisers, and edits that keep the two
in step (densifiers and pruning initializers add and remove Gaussians mid-training)."""

from __future__ import annotations

from collections.abc import Mapping

import attrs
import torch

from mmcsplat.plugin_api.parameters import finite_positive, parameter
from mmcsplat.plugin_api.render_contract import Gaussians, gaussians_from_params
from mmcsplat.scene.gaussian_table import GAUSSIAN_PARAMETERS


@attrs.frozen
class LearningRates:
    """Adam learning rates of the reference study (means are scaled by the scene scale)."""

    means: float = parameter(1.6e-4, doc="of the means, times the scene scale", validator=finite_positive)
    quats: float = parameter(1e-3, doc="of the rotations", validator=finite_positive)
    log_scales: float = parameter(1e-3, doc="of the log-scales", validator=finite_positive)
    opacity_logits: float = parameter(5e-2, doc="of the opacity logits", validator=finite_positive)
    color_logits: float = parameter(2.5e-3, doc="of the colour logits", validator=finite_positive)
    seg_logits: float = parameter(1e-3, doc="of the segmentation logits", validator=finite_positive)
    camera_color: float = parameter(1e-4, doc="of each camera's colour scale and offset", validator=finite_positive)


class GaussianModel:
    """Leaf tensors for N Gaussians plus a per-camera colour scale and offset, each with its own Adam.

    Colours and the one-channel segmentation colour are stored as logits and rendered through a sigmoid,
    as the reference study does; opacities through a sigmoid, scales through exp.
    """

    def __init__(self, gaussians: Gaussians, camera_names: tuple[str, ...], lrs: LearningRates, scene_scale: float) -> None:
        # features[:, 0] is the segmentation colour to start from; without one, 0.5: undecided, as initializers start it.
        seg = gaussians.features[:, :1] if gaussians.features.shape[1] else torch.full_like(gaussians.means[:, :1], 0.5)
        self.params: dict[str, torch.Tensor] = {
            "means": gaussians.means,
            "quats": gaussians.quats,
            "log_scales": gaussians.log_scales,
            "opacity_logits": gaussians.opacity_logits,
            "color_logits": torch.logit(gaussians.colors.clamp(1e-4, 1 - 1e-4)),
            "seg_logits": torch.logit(seg.clamp(1e-4, 1 - 1e-4)),
        }
        self.params = {name: value.detach().clone().float().requires_grad_(True) for name, value in self.params.items()}
        self.camera_names = camera_names
        count = len(camera_names)
        self.camera_scale = torch.ones(count, 3, requires_grad=True)
        self.camera_offset = torch.zeros(count, 3, requires_grad=True)
        rates = attrs.asdict(lrs)
        rates["means"] = lrs.means * scene_scale
        self.optimizers: dict[str, torch.optim.Adam] = {
            name: torch.optim.Adam([tensor], lr=rates[name], eps=1e-15) for name, tensor in self.params.items()
        }
        self.optimizers["camera"] = torch.optim.Adam([self.camera_scale, self.camera_offset], lr=lrs.camera_color, eps=1e-15)

    @classmethod
    def from_params(
        cls,
        params: Mapping[str, torch.Tensor],
        camera_names: tuple[str, ...],
        lrs: LearningRates,
        scene_scale: float,
        camera_scale: torch.Tensor | None = None,
        camera_offset: torch.Tensor | None = None,
    ) -> GaussianModel:
        """A model holding exactly the stored ``params`` (and colour terms), with fresh optimisers: to go on
        from a fitted frame (logits are kept as they are, not round-tripped through a sigmoid)."""
        model = cls(gaussians_from_params(params), camera_names, lrs, scene_scale)
        state = model.state_dict()
        state["params"] = {name: params[name].detach().float() for name in GAUSSIAN_PARAMETERS}
        for key, value in (("camera_scale", camera_scale), ("camera_offset", camera_offset)):
            if value is not None:
                state[key] = value.detach().float()
        model.load_state_dict(state)
        return model

    @property
    def count(self) -> int:
        return int(self.params["means"].shape[0])

    def gaussians(self) -> Gaussians:
        """The renderable Gaussians (colours and segmentation through a sigmoid)."""
        return gaussians_from_params(self.params)

    def correct_color(self, rgb: torch.Tensor, camera_index: int) -> torch.Tensor:
        """Apply a camera's learnable colour scale and offset to a rendered [H, W, 3] image."""
        return rgb * self.camera_scale[camera_index] + self.camera_offset[camera_index]

    def step(self) -> None:
        for optimizer in self.optimizers.values():
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)

    # ---------------------------------------------------------------- topology edits (densify, prune)

    def replace(self, edit: Mapping[str, torch.Tensor], keep: torch.Tensor | None) -> None:
        """Rebuild every per-Gaussian parameter as ``concat(old[keep], edit[name])``.

        ``keep`` [N] bool selects surviving Gaussians (all when None); ``edit`` holds the new Gaussians'
        values per parameter (omitted names get no new rows); new Gaussians start with zero Adam moments."""
        n = self.count
        keep = torch.ones(n, dtype=torch.bool) if keep is None else keep
        added = next(iter(edit.values())).shape[0] if edit else 0
        for name in GAUSSIAN_PARAMETERS:
            old = self.params[name]
            pieces = [old.detach()[keep]]
            if added:
                pieces.append(edit[name].detach().to(old.dtype))
            new = torch.cat(pieces).requires_grad_(True)
            optimizer = self.optimizers[name]
            state = optimizer.state.pop(old, None)
            optimizer.param_groups[0]["params"] = [new]
            if state is not None:
                for key in ("exp_avg", "exp_avg_sq"):
                    moments = [state[key][keep]]
                    if added:
                        moments.append(torch.zeros((added, *old.shape[1:])))
                    state[key] = torch.cat(moments)
                optimizer.state[new] = state
            self.params[name] = new

    def reset_moments(self, names: tuple[str, ...]) -> None:
        """Forget Adam's moments of the named parameters (dynamics resets means and rotations per frame)."""
        for name in names:
            self.optimizers[name].state.pop(self.params[name], None)

    def state_dict(self) -> dict:
        return {
            "params": {name: tensor.detach().clone() for name, tensor in self.params.items()},
            "camera_scale": self.camera_scale.detach().clone(),
            "camera_offset": self.camera_offset.detach().clone(),
            "optimizers": {name: optimizer.state_dict() for name, optimizer in self.optimizers.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        for name in GAUSSIAN_PARAMETERS:
            tensor = state["params"][name].clone().requires_grad_(True)
            self.params[name] = tensor
            self.optimizers[name].param_groups[0]["params"] = [tensor]
            self.optimizers[name].state.clear()
        with torch.no_grad():
            self.camera_scale.copy_(state["camera_scale"])
            self.camera_offset.copy_(state["camera_offset"])
        for name, optimizer in self.optimizers.items():
            optimizer.load_state_dict(state["optimizers"][name])
