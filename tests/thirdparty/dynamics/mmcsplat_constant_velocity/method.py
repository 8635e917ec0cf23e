"""``constant-velocity``: a baseline dynamics method. The foreground Gaussians move together by one
translation per frame, predicted from the last two frames at constant velocity, then refined by a few
Adam steps of the first-frame fit's training step (mmcsplat.training.loop); the background stays where
the fit left it. It cannot follow limbs that move against the trunk, which is what makes it a reference row: a method with local
motion should beat it wherever the subject does more than drift.

Imports only mmcsplat's public API (plugin_api, storage, training), as any third-party plugin must.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import attrs
import torch

from mmcsplat.plugin_api.interfaces import Dynamics, TrackingContext
from mmcsplat.plugin_api.parameters import above, at_least, between, parameter
from mmcsplat.plugin_api.render_contract import RenderCameras, gaussians_from_params
from mmcsplat.storage.tracks import TrackWriter
from mmcsplat.training.loop import Sample, Step, TrainingLoop
from mmcsplat.training.model import GaussianModel


@attrs.frozen
class ConstantVelocityDynamics(Dynamics):
    """One translation of the foreground per frame: constant-velocity prediction, then refinement."""

    iterations: int = parameter(20, doc="Adam steps per frame on the translation (0: prediction only)", validator=at_least(0))
    lr: float = parameter(1e-3, doc="learning rate of the translation, metres", validator=above(0))
    foreground: float = parameter(0.5, doc="segmentation colour above which a Gaussian moves", validator=between(0, 1))

    def track(self, context: TrackingContext, out: Path) -> dict[str, Any]:
        """Write every frame's means: the fit's, the foreground shifted by that frame's translation."""
        model = GaussianModel.from_params(context.params, tuple(c.name for c in context.cameras), context.settings.lrs,
                                          context.scene_scale, context.camera_scale, context.camera_offset)
        model.camera_scale.requires_grad_(False)  # the fit's colour terms stay as fitted
        model.camera_offset.requires_grad_(False)
        params = {name: value.detach() for name, value in model.params.items()}
        moving = (torch.sigmoid(params["seg_logits"][:, 0]) > self.foreground).to(params["means"].dtype)[:, None]
        cameras = RenderCameras.each(context.cameras)
        static = {name: value for name, value in params.items() if name not in ("means", "quats")}
        shifts = [torch.zeros(3, dtype=params["means"].dtype)] * 2
        psnrs: list[float] = []
        with TrackWriter(out, num_frames=len(context.frames), static=static, method="constant-velocity",
                         attrs={"moving_gaussians": int(moving.sum())}, overwrite=context.overwrite) as writer:
            writer.write_frame(0, means=params["means"], quats=params["quats"])
            for k, t in enumerate(context.frames[1:], start=1):
                shift = (2 * shifts[-1] - shifts[-2]).clone().requires_grad_(True)
                optimizer = torch.optim.Adam([shift], lr=self.lr)
                views = context.views(t)

                def sample(step: int) -> Sample:
                    view = views[step % len(views)]
                    moved = gaussians_from_params(params | {"means": params["means"] + moving * shift})
                    return Sample(view, cameras[view.index], moved)

                def record(step: Step) -> None:
                    if step.number == self.iterations - 1:
                        psnrs.append(step.psnr())
                        context.curve.log(step=k * self.iterations, frame=t, loss=step.loss.item(), psnr=psnrs[-1])

                if views:  # the model's own parameters get no gradient: only the shift's optimiser steps
                    loop = TrainingLoop(model, context.renderer, context.settings, optimizers=[lambda step: self._step(optimizer)])
                    loop.run(range(self.iterations), sample, record=record, where=f"frame {t}", progress=False)
                shifts.append(shift.detach())
                writer.write_frame(k, means=params["means"] + moving * shifts[-1], quats=params["quats"])
        return {"iterations_per_frame": self.iterations, "moving_gaussians": int(moving.sum()),
                "shifts_m": [s.tolist() for s in shifts[2:]], "last_psnr": psnrs}

    @staticmethod
    def _step(optimizer: torch.optim.Optimizer) -> None:
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
