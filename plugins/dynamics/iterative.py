"""The ``iterative`` dynamics (Luiten et al. 2023, as the reference study used it): every frame is fitted
from the previous one, moved ahead — the foreground by the session's optical flow lifted to 3D where it has
flow (:mod:`mmcsplat.training.flow_prediction`), everything else at constant velocity — with
local-rigidity priors holding the foreground together.

Per frame: ``iterations`` Adam steps, each on one training camera (a fresh random order per pass over
the cameras present in that frame), of L_im + λ_seg·L_seg + λ_rigid·L_rigid + λ_rot·L_rot + λ_iso·L_iso.
After the first frame opacities, scales and the per-camera colour terms are frozen; means, rotations
and (as Luiten's) colours keep learning, and Adam forgets the means' and rotations' moments at each new
frame. Only the current frame's images are held.

Each step is the fit's training step (:class:`~mmcsplat.training.loop.TrainingLoop`) with the priors as
its extra loss term. It leaves out the initializers' extra losses and pruning: they are defined on the
first frame's scene (its depth maps, its region), and pruning would change the set of Gaussians every
frame of the tracks holds.

Options: ``flow_gain`` multiplies the lifted flow in each frame's prediction (``mmcsplat run`` doubles it: the
flow reports about three quarters of a real limb's motion); ``lambda_flow`` adds the flow loss (:mod:`mmcsplat.training.motion_image`: the rendered motion
since the previous frame against the session's observed flow on the subject's pixels);
``lambda_keypoints`` adds keypoint guidance (:mod:`mmcsplat.training.keypoint_guidance`: the Gaussians
carrying each keypoint of the ``keypoints`` source pulled towards the training cameras' detections; off by
default); ``lambda_parts`` holds the Gaussians of each body part, found from the ``skeleton`` source's joints at
the first frame, at their first-frame distances (:mod:`.body_parts`; off by default, on in ``mmcsplat run``
with the capture's joints); ``coarse_iterations`` fits each frame's first steps at reduced resolution
(:mod:`mmcsplat.training.coarse_views`); ``stop_window``
ends a frame's fit when its loss stops improving (:class:`~mmcsplat.training.loop.PlateauStop`), with
``iterations`` the cap; ``track.json`` records each frame's iterations. ``lr_final_ratio`` decays the means'
and rotations' learning rates over each frame's steps, so a frame ends settled.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Literal

import attrs
import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Dynamics, LandmarkSource, TrackingContext, TrainingView
from mmcsplat.plugin_api.parameters import above, at_least, between, one_of, parameter
from mmcsplat.plugin_api.render_contract import RenderCameras, RenderOutput
from mmcsplat.scene.gaussian_table import GAUSSIAN_PARAMETERS
from mmcsplat.scene.human_skeleton import with_midpoints
from mmcsplat.storage.session.flow import FlowPair, SessionFlow, pair_present
from mmcsplat.storage.tracks import TrackWriter
from mmcsplat.training.coarse_views import CoarseToFine
from mmcsplat.training.flow_prediction import FlowGuidance, FlowPrediction
from mmcsplat.training.frame_steps import AUTO_STEPS, FEWEST_STEPS, STEPS_PER_SECOND, checked_steps, steps_per_frame
from mmcsplat.training.keypoint_guidance import KeypointGuidance
from mmcsplat.training.loop import LossTerm, OptimizerStep, PlateauStop, Sample, Step, TrainingLoop
from mmcsplat.training.model import GaussianModel
from mmcsplat.training.motion_image import FlowLoss, with_motion
from mmcsplat.training.schedule import CameraSchedule

from .body_parts import HUMAN_PARTS, PartPairs
from .rigidity import NeighbourGraph, RigidityPrior

FROZEN = ("opacity_logits", "log_scales")
COLORS = ("color_logits", "seg_logits")
RESET_EACH_FRAME = ("means", "quats")

logger = logging.getLogger(__name__)


def _steps(_instance: Any, field: attrs.Attribute, value: Any) -> None:
    """Validator: a whole number of steps ≥ 0, or ``auto`` (:func:`~mmcsplat.training.frame_steps.checked_steps`)."""
    try:
        checked_steps(value)
    except ValueError as error:
        raise ValueError(f"{field.name}: {error}") from error


@attrs.frozen
class FrameResult:
    """How one frame's fit ended: the mean over its cameras of each one's last loss and PSNR (``None``
    when no training camera holds the frame), and its wall-clock and CPU time (on a shared machine the
    CPU time is the steadier measure)."""

    frame: int
    iterations: int
    loss: float | None
    psnr: float | None
    cameras: int
    wall_s: float
    cpu_s: float


@attrs.frozen
class IterativeDynamics(Dynamics):
    """Per-frame optimisation with constant-velocity prediction and local-rigidity priors; the neighbour
    graph over the foreground Gaussians is built once after the first frame."""

    cameras_per_frame: ClassVar[int] = 2  # each frame is fitted from its own images alone

    iterations: int | Literal["auto"] = parameter(AUTO_STEPS, doc=f"Adam steps per frame, one training camera each, or auto: "
                                                  f"{STEPS_PER_SECOND:g} a second of video and {FEWEST_STEPS} at least (50 at 60 fps, 100 at "
                                                  "30), since frames further apart leave a limb further to reach (the reference study's "
                                                  "2000 take hours a frame on a real capture on a CPU)", validator=_steps)
    neighbours: int = parameter(20, doc="k of the neighbour graph over foreground Gaussians", validator=at_least(1))
    neighbour_stride: int = parameter(1, doc="each Gaussian's neighbours are every neighbour_stride-th of its neighbours·neighbour_stride "
                                      "nearest: a longer reach at the same cost per step (1: the nearest)", validator=at_least(1))
    lambda_w: float = parameter(2000.0, doc="neighbour weights exp(−lambda_w·d²), d in metres", validator=at_least(0))
    lambda_rigid: float = parameter(4.0, doc="weight of the local-rigidity prior", validator=at_least(0))
    rigid_reference: str = parameter("previous", doc="the frame the rigid and rotation priors compare with: 'previous' (Luiten's: "
                                     "each frame's small slide is forgiven) or 'first' (slides add up)", validator=one_of("previous", "first"))
    lambda_rot: float = parameter(4.0, doc="weight of the rotation-similarity prior", validator=at_least(0))
    lambda_iso: float = parameter(2.0, doc="weight of the isometry prior", validator=at_least(0))
    lambda_seg: float | None = parameter(None, doc="weight of the segmentation loss (none: the fit's)", validator=at_least(0))
    foreground: float = parameter(0.5, doc="segmentation colour above which a Gaussian is foreground", validator=between(0, 1))
    means_lr: float | None = parameter(1.6e-3, doc="learning rate of the means, scaled by the scene scale: ten times the fit's, since "
                                       "Adam moves a mean by about its rate a step and a frame's few dozen steps must reach a limb the "
                                       "prediction left centimetres short (none: the fit's)", validator=above(0))
    quats_lr: float | None = parameter(None, doc="learning rate of the rotations (none: the fit's)", validator=above(0))
    lr_final_ratio: float = parameter(1.0, doc="the means' and rotations' learning rates decay exponentially over each frame's "
                                      "iterations to this fraction of theirs, so a frame ends settled rather than where Adam's "
                                      "last lr-sized steps left it (1: constant; 0 would stop every step after a frame's first)",
                                      validator=attrs.validators.and_(above(0), between(0, 1)))
    learn_colors: bool = parameter(True, doc="colours keep learning after the first frame (as Luiten et al.)")
    seed: int = parameter(0, doc="seed of the camera order")
    predict: str = parameter("flow", doc="each frame's start: 'flow' moves the foreground by the session's optical flow lifted to 3D "
                             "(constant velocity without flow), 'constant-velocity' moves everything by its last change",
                             validator=one_of("flow", "constant-velocity"))
    flow_gain: float = parameter(1.0, doc="the lifted flow's displacement is multiplied by this in the prediction: DIS reports about "
                                 "three quarters of a real limb's motion (docs/results.md, \"The flow's shortfall\")", validator=above(0))
    lambda_flow: float = parameter(0.0, doc="weight of the flow loss: rendered motion since the previous frame against the session's "
                                   "optical flow on the subject's pixels, in pixels (0: off; needs `mmcsplat flow`)", validator=at_least(0))
    stop_window: int = parameter(0, doc="end a frame's fit when the mean loss over this many steps stops improving (0: always "
                                 "`iterations`, the cap)", validator=at_least(0))
    stop_tolerance: float = parameter(0.0, doc="relative improvement of that mean below which the frame has converged",
                                      validator=at_least(0))
    coarse_iterations: int = parameter(0, doc="each frame's first steps at 1/coarse_factor resolution, so a limb that moved "
                                       "more than its width still has a gradient (0: off)", validator=at_least(0))
    lambda_keypoints: float = parameter(0.0, doc="weight of keypoint guidance: the Gaussians carrying each keypoint pulled towards the "
                                        "training cameras' detections, Huber distance in pixels (0: off; needs keypoints)", validator=at_least(0))
    keypoints: Mapping[str, Any] = parameter(doc="the keypoint source of the guidance: a landmarks plugin's name and parameters, e.g. "
                                             "{name = \"openpose\", folder = \"pose_2d\"}", factory=dict, converter=dict)
    keypoint_huber_px: float = parameter(2.0, doc="pixels (of the stored images) beyond which a keypoint's pull stops growing",
                                         validator=above(0))
    lambda_parts: float = parameter(0.0, doc="weight of the length prior within body parts: pairs of Gaussians on one part (a "
                                    "forearm, the torso), found from the skeleton's joints at the first frame, keep their first-frame "
                                    "distance (0: off; needs a skeleton)", validator=at_least(0))
    skeleton: Mapping[str, Any] = parameter(doc="the joints that define the parts, at the first frame: a landmarks plugin's name and "
                                            "parameters, e.g. {name = \"trc\", path = \"joints.trc\"}", factory=dict, converter=dict)
    part_partners: int = parameter(8, doc="pairs drawn for each Gaussian on a part", validator=at_least(1))
    part_reach: float = parameter(0.15, doc="a Gaussian belongs to a part within this share of the torso length of its joints' "
                                  "segments", validator=above(0))
    part_margin: float = parameter(0.02, doc="... and to every other part within this share of the torso length more (a "
                                   "Gaussian at a joint belongs to both of its parts; 0: to its nearest part only)", validator=at_least(0))
    coarse_factor: int = parameter(2, doc="resolution reduction of the coarse steps (pixel blocks averaged)", validator=at_least(2))

    @property
    def reads_flow(self) -> bool:
        """Flow-guided prediction and the flow loss read the session's optical flow."""
        return self.predict == "flow" or self.lambda_flow > 0

    # ------------------------------------------------------------------------------------------ setup

    def _model(self, context: TrackingContext) -> GaussianModel:
        lrs = context.settings.lrs
        lrs = attrs.evolve(lrs, means=self.means_lr if self.means_lr is not None else lrs.means,
                           quats=self.quats_lr if self.quats_lr is not None else lrs.quats)
        model = GaussianModel.from_params(context.params, tuple(c.name for c in context.cameras), lrs, context.scene_scale,
                                          context.camera_scale, context.camera_offset)
        for name in self._static_names():
            model.params[name].requires_grad_(False)
        model.camera_scale.requires_grad_(False)
        model.camera_offset.requires_grad_(False)
        return model

    def _static_names(self) -> tuple[str, ...]:
        return FROZEN if self.learn_colors else FROZEN + COLORS

    def _dynamic(self, model: GaussianModel) -> dict[str, torch.Tensor]:
        return {name: model.params[name].detach() for name in GAUSSIAN_PARAMETERS if name not in self._static_names()}

    # --------------------------------------------------------------------------------------- tracking

    def track(self, context: TrackingContext, out: Path) -> dict[str, Any]:
        """Fit every frame after the first; returns per-frame results and the neighbour graph's size."""
        from tqdm import tqdm

        if self.iterations == AUTO_STEPS:
            fps = context.session.fps / context.frames.step
            steps = steps_per_frame(AUTO_STEPS, fps)
            logger.info("iterative: %d steps a frame (auto: %g a second of video at %g fps, %d at least)", steps, STEPS_PER_SECOND, fps,
                        FEWEST_STEPS)
            return attrs.evolve(self, iterations=steps).track(context, out)
        if 0 < self.iterations <= self.coarse_iterations:
            raise InputError(f"dynamics.coarse_iterations = {self.coarse_iterations} leaves none of the {self.iterations} iterations per frame "
                             "at full size: set it below dynamics.iterations")
        model = self._model(context)
        params = model.params
        foreground = torch.sigmoid(params["seg_logits"].detach()[:, 0]) > self.foreground
        graph = NeighbourGraph.build(params["means"], foreground, self.neighbours, self.lambda_w, self.neighbour_stride)
        prior = RigidityPrior(graph, self.rigid_reference)
        flow = self._loss_flow(context)
        flow_loss = FlowLoss(self.lambda_flow) if flow is not None else None
        guidance = self._keypoint_guidance(context, params, foreground)
        pairs = self._part_pairs(context, params, foreground)
        terms = [self._rigidity(prior, model, pairs), *([flow_loss] if flow_loss is not None else []),
                 *([guidance.term(params)] if guidance is not None else [])]
        loop = TrainingLoop(model, context.renderer, context.settings, lambda_seg=self.lambda_seg, terms=terms,
                            optimizers=[self._settling(model)] if self.lr_final_ratio < 1 else [])
        stop = PlateauStop(self.stop_window, tolerance=self.stop_tolerance) if self.stop_window else None
        cameras = RenderCameras.each(context.cameras)
        generator = torch.Generator().manual_seed(self.seed)
        static = {name: params[name].detach() for name in self._static_names()}
        attributes = {"first_frame": context.frames.start, "foreground_gaussians": len(graph.foreground),
                      "neighbours": int(graph.neighbours.shape[1]), "lambda_w": self.lambda_w}
        results: list[FrameResult] = []
        motion = self._flow_prediction(context, foreground)
        with TrackWriter(out, num_frames=len(context.frames), static=static, method="iterative", attrs=attributes,
                         overwrite=context.overwrite) as writer:
            writer.write_frame(0, **self._dynamic(model))
            previous = (params["means"].detach().clone(), self._unit(params["quats"].detach()))
            frames = tqdm(list(enumerate(context.frames))[1:], desc="track", unit="frame", disable=not context.progress)
            for k, t in frames:
                prior.remember(params["means"], params["quats"])
                previous = self._predict(model, previous, motion, context.frames[k - 1])
                model.reset_moments(RESET_EACH_FRAME)
                if flow_loss is not None:
                    flow_loss.observe(self._flow_pairs(flow, context, t))
                if guidance is not None:
                    guidance.observe(t)
                result = self._fit_frame(loop, context, cameras, t, generator, previous[0] if flow_loss is not None else None, stop)
                results.append(result)
                writer.write_frame(k, **self._dynamic(model))
                if result.loss is not None:
                    context.curve.log(step=sum(r.iterations for r in results), frame=t, loss=result.loss, psnr=result.psnr, gaussians=model.count)
                    frames.set_postfix(loss=f"{result.loss:.4f}", psnr=f"{result.psnr:.2f}")
        return {
            "iterations_per_frame": self.iterations,
            "foreground_gaussians": len(graph.foreground),
            "neighbour_distance_median_m": float(graph.distances.median()),
            "frames": [attrs.asdict(result) for result in results],
            "prediction": "constant-velocity" if motion is None else "flow",
            "flow_loss": flow_loss is not None,
            "keypoint_guidance": guidance.summary() if guidance is not None else None,
            "body_parts": pairs.summary() if pairs is not None else None,
            **({"flow_fallback_gaussians": motion.fallbacks} if motion is not None else {}),
        }

    def _rigidity(self, prior: RigidityPrior, model: GaussianModel, pairs: PartPairs | None) -> LossTerm:
        """The weighted local-rigidity priors, and the parts' length prior, as one loss term."""
        def term(step: int, render: RenderOutput, view: TrainingView) -> torch.Tensor:
            rigid, rot, iso = prior.losses(model.params["means"], model.params["quats"])
            total = self.lambda_rigid * rigid + self.lambda_rot * rot + self.lambda_iso * iso
            return total + self.lambda_parts * pairs.loss(model.params["means"]) if pairs is not None else total
        return term

    def _part_pairs(self, context: TrackingContext, params: Mapping[str, torch.Tensor], foreground: torch.Tensor) -> PartPairs | None:
        """The parts' pairs from the ``skeleton`` source's joints at the first frame, when ``lambda_parts``
        asks for them; an error naming what is missing when they cannot be had."""
        if self.lambda_parts == 0:
            return None
        _, source = self._landmark_source(context, self.skeleton, "dynamics.lambda_parts needs the joints that define the parts: set "
                                          "dynamics.skeleton.name=trc and dynamics.skeleton.path=…, or dynamics.lambda_parts=0")
        first = context.frames.start
        landmarks = source.read(context.session, [first])
        joints = with_midpoints({joint: position for joint, position in zip(landmarks.names, landmarks.at(first), strict=True)
                                 if np.isfinite(position).all()})
        pairs = PartPairs.build(params["means"], np.flatnonzero(foreground.numpy()), joints, HUMAN_PARTS, self.part_partners,
                                self.part_reach, self.part_margin, self.seed)
        logger.info("iterative: %d pairs over %d body parts (%s Gaussians) from %s", len(pairs.first), len(pairs.parts),
                    "/".join(str(n) for n in pairs.members), landmarks.source)
        return pairs

    def _settling(self, model: GaussianModel) -> OptimizerStep:
        """Sets the means' and rotations' learning rates for step ``n`` of a frame: theirs times
        ``lr_final_ratio ** (n / (iterations − 1))``."""
        rates = {name: model.optimizers[name].param_groups[0]["lr"] for name in RESET_EACH_FRAME}

        def settle(step: int) -> None:
            factor = self.lr_final_ratio ** (step / max(self.iterations - 1, 1))
            for name, rate in rates.items():
                model.optimizers[name].param_groups[0]["lr"] = rate * factor
        return settle

    def _loss_flow(self, context: TrackingContext) -> SessionFlow | None:
        """The session's flow for the flow loss when ``lambda_flow`` asks for it; an error naming the session
        when it cannot be had."""
        if self.lambda_flow == 0:
            return None
        if context.frames.step != 1:
            raise InputError(f"dynamics.lambda_flow needs consecutive frames (the flow links frame t to t+1), but the frames step by "
                             f"{context.frames.step}: track every frame or set dynamics.lambda_flow=0")
        flow = SessionFlow(context.session.url)
        if not any(flow.has(camera.name) for camera in context.cameras):
            raise InputError(f"dynamics.lambda_flow needs the optical flow of {context.session.url}, which has none in the training "
                             f"cameras: run `mmcsplat flow {context.session.url}` or set dynamics.lambda_flow=0")
        return flow

    def _keypoint_guidance(self, context: TrackingContext, params: Mapping[str, torch.Tensor],
                           foreground: torch.Tensor) -> KeypointGuidance | None:
        """Keypoint guidance from the ``keypoints`` source when ``lambda_keypoints`` asks for it, bound at the
        first frame; an error naming what is missing when it cannot be had."""
        if self.lambda_keypoints == 0:
            return None
        name, source = self._landmark_source(context, self.keypoints, "dynamics.lambda_keypoints needs a keypoint source: set "
                                             "dynamics.keypoints.name=openpose (or deeplabcut, sleap) and its dynamics.keypoints.folder=…, "
                                             "or dynamics.lambda_keypoints=0")
        observations = source.observations(context.session, list(context.frames))
        if not observations:
            raise InputError(f"dynamics.keypoints: landmarks {name!r} gives no 2D detections to guide with: name a keypoint source "
                             "(openpose, deeplabcut, sleap)")
        return KeypointGuidance.bind(observations, context.cameras, list(context.frames), params, np.flatnonzero(foreground.numpy()),
                                     self.lambda_keypoints, self.keypoint_huber_px)

    @staticmethod
    def _landmark_source(context: TrackingContext, table: Mapping[str, Any], missing: str) -> tuple[str, LandmarkSource]:
        """The landmarks plugin ``table`` names (``name`` and its parameters), and that name; ``missing`` is the
        error when the table names none."""
        params = dict(table)
        if "name" not in params:
            raise InputError(missing)
        name = params.pop("name")
        return name, context.plugins.create("landmarks", name, **params)

    @staticmethod
    def _flow_pairs(flow: SessionFlow, context: TrackingContext, t: int) -> dict[str, FlowPair]:
        """Each training camera's stored flow from session frame ``t − 1`` to ``t``, where it has that pair."""
        return {camera.name: flow.pair(t - 1, camera.name) for camera in context.cameras
                if flow.has(camera.name) and pair_present(flow.present(camera.name))[t - 1]}

    @staticmethod
    def _unit(quats: torch.Tensor) -> torch.Tensor:
        return quats / quats.norm(dim=-1, keepdim=True)

    def _flow_prediction(self, context: TrackingContext, foreground: torch.Tensor) -> FlowGuidance | None:
        """The flow the foreground is predicted from, or ``None`` (constant velocity, with a note why in the
        run's log; ``track.json``'s ``prediction`` says which was used)."""
        if self.predict != "flow":
            return None
        if context.frames.step != 1:
            logger.info("iterative: frames step by %d; the flow links consecutive frames: constant-velocity prediction", context.frames.step)
            return None
        prediction = FlowPrediction.of_session(context.session.url, context.cameras, context.renderer)
        if prediction is None:
            logger.info("iterative: %s has no optical flow in two training cameras (`mmcsplat flow` computes it): "
                           "constant-velocity prediction", context.session.url)
            return None
        return FlowGuidance(prediction, foreground, self.flow_gain)

    def _predict(self, model: GaussianModel, previous: tuple[torch.Tensor, torch.Tensor], motion: FlowGuidance | None = None,
                 t: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
        """Move means and rotations ahead by their last frame-to-frame change — the foreground's means by the
        flow from session frame ``t`` instead, where ``motion`` lifts it; returns the current state (the
        "previous" of the next prediction)."""
        params = model.params
        means, quats = params["means"].detach().clone(), self._unit(params["quats"].detach())
        prev_means, prev_quats = previous
        # q and −q are one rotation: take the previous one on the current one's side before extrapolating.
        prev_quats = torch.where((prev_quats * quats).sum(-1, keepdim=True) < 0, -prev_quats, prev_quats)
        predicted = 2 * means - prev_means if motion is None else motion.predict(model.gaussians(), prev_means, t)
        with torch.no_grad():
            params["means"].copy_(predicted)
            params["quats"].copy_(self._unit(2 * quats - prev_quats))
        return means, quats

    def _fit_frame(self, loop: TrainingLoop, context: TrackingContext, cameras: tuple[RenderCameras, ...], t: int,
                   generator: torch.Generator, previous_means: torch.Tensor | None, stop: PlateauStop | None) -> FrameResult:
        """Fit session frame ``t``; with ``previous_means`` each render carries the motion image since them."""
        began, cpu = time.perf_counter(), time.process_time()
        views = context.views(t)
        if not views:
            return FrameResult(t, 0, None, None, 0, time.perf_counter() - began, time.process_time() - cpu)
        schedule = CameraSchedule(len(views), generator)
        stages = CoarseToFine(views, cameras, self.coarse_factor, min(self.coarse_iterations, self.iterations))
        recent: dict[int, tuple[float, float]] = {}

        def sample(step: int) -> Sample:
            view, view_cameras = stages.at(step, schedule.next())
            gaussians = loop.model.gaussians()
            if previous_means is not None:
                gaussians = with_motion(gaussians, previous_means, view_cameras)
            return Sample(view, view_cameras, gaussians)

        def remember(step: Step) -> None:  # each camera's last full-size loss and PSNR (every 10th step, all of the last pass;
            # all of them when the frame may stop early)
            last_pass = step.number >= self.iterations - len(views) or step.number % 10 == 0 or stop is not None
            if step.number >= stages.coarse_steps and last_pass:
                recent[step.view.index] = (step.loss.item(), step.psnr())

        run = functools.partial(loop.run, sample=sample, record=remember, where=f"frame {t}", desc=f"frame {t}",
                                progress=context.progress, leave=False)
        if stages.coarse_steps:  # the stopping rule judges the full-size steps only: their losses compare
            run(range(stages.coarse_steps))
        done = run(range(stages.coarse_steps, self.iterations), stop=stop)
        last = np.array(list(recent.values())).reshape(-1, 2)
        mean = last.mean(axis=0).tolist() if len(last) else [None, None]
        return FrameResult(t, done, mean[0], mean[1], len(views), time.perf_counter() - began, time.process_time() - cpu)
