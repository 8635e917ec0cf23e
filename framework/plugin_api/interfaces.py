"""The interface of each plugin kind. A plugin's factory (see :mod:`mmcsplat.plugin_api.hookspecs`) returns an object
implementing one of these; docs/plugins.md explains how to write, register and test each.

The core depends on these abstractions only, never on a concrete plugin. What the pipeline hands to
plugins — :class:`SceneContext`, :class:`TrainingView`, :class:`TrackingContext` — are pure records
defined here beside the interfaces that receive them; the render contract is in
:mod:`mmcsplat.plugin_api.render_contract`.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.registration import PluginBuilder
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.visual_hull import hull_cells, region_reach
from mmcsplat.storage.curves import TrainingCurve

if TYPE_CHECKING:  # heavy imports only for type checkers
    import torch

    from mmcsplat.storage.session import SessionReader
    from mmcsplat.storage.session.format import SessionFrame
    from mmcsplat.training.model import GaussianModel
    from mmcsplat.training.settings import FitSettings

    from .render_contract import Gaussians, RenderCameras, RenderOutput


# ----------------------------------------------------------------------------------------------- readers


@attrs.frozen(eq=False)
class RecordedFrame:
    """One image of a capture as a reader yields it: ``rgb`` [H, W, 3] uint8, an optional subject ``mask``
    [H, W] bool and ``depth`` [H, W] float metres (formats that ship them, such as the synthetic capture's
    ground truth; 0 where there is no surface), and its frame index ``t``."""

    t: int
    rgb: np.ndarray
    mask: np.ndarray | None = None
    depth: np.ndarray | None = None


class Recording(ABC):
    """An opened capture: calibrated cameras (possibly distorted) and their frames, decoded on demand."""

    #: Cameras as calibrated; ingest undistorts frames and stores zero-distortion cameras.
    cameras: Sequence[Camera]
    #: Frames per second, and the number of frame indices (the union over cameras).
    fps: float
    num_frames: int
    #: Cameras the format itself marks as held out for evaluation (e.g. d3dgs test cameras).
    heldout: Sequence[str] = ()
    #: Whether frames come with subject masks and depth maps.
    has_masks: bool = False
    has_depth: bool = False

    @abstractmethod
    def frames(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        """Yield the frames of ``camera`` whose index is in ``indices``, in order, skipping absent ones."""

    def present(self, camera: str) -> np.ndarray:
        """[num_frames] bool: which frame indices exist for ``camera`` (all, unless the format is sparse,
        like D-NeRF's one camera per time step)."""
        return np.ones(self.num_frames, dtype=bool)

    def frame_times(self) -> np.ndarray:
        """[num_frames] seconds of each frame index."""
        return np.arange(self.num_frames, dtype=np.float64) / self.fps

    def source_frames(self, camera: str) -> np.ndarray:
        """[num_frames] int: the number of each frame index in ``camera``'s own source — its video's frame,
        which 2D keypoints detected in that video are numbered by — or −1 where the camera lacks it. The frame
        index itself, unless the format places a camera's frames otherwise (a Caliscope camera that missed a
        moment is a frame behind the others from there on)."""
        return np.where(self.present(camera), np.arange(self.num_frames), -1)

    def describe(self) -> dict[str, Any]:
        """Provenance stored in the session's attributes."""
        return {}

    def close(self) -> None:
        """Release decoders and files."""


class Reader(ABC):
    """A capture format: recognises a source folder and opens it as a :class:`Recording`."""

    @abstractmethod
    def detect(self, source: Path) -> bool:
        """Whether ``source`` looks like this format (cheap: file names, not decoding)."""

    @abstractmethod
    def open(self, source: Path, calibration: Path | None = None, units: str = "auto") -> Recording:
        """Open ``source``; ``calibration`` overrides the format's own, ``units`` is the calibration's
        length unit ("m" or "mm"), or "auto" (ingest's default): the reader decides — a calibration file by
        the extent of its rig (``mmcsplat.storage.calibration.read_rig``), poses that carry no unit of their
        own in metres. Errors name the file or camera at fault."""


# --------------------------------------------------------------------------------------------- renderers


class Renderer(ABC):
    """A differentiable Gaussian rasterizer honouring the contract of :mod:`mmcsplat.plugin_api.render_contract`."""

    @abstractmethod
    def render(
        self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None
    ) -> RenderOutput:
        """Render every camera; differentiable with respect to all Gaussian parameters."""


# -------------------------------------------------------------------------------------------- segmenters


class Segmenter(ABC):
    """Produces subject masks (and optional semantic labels) for the frames of a session."""

    @abstractmethod
    def segment(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        """Yield (t, mask [H, W] bool, labels [H, W] uint16 or None) for every frame of ``camera``."""


# ------------------------------------------------------------------------------------------ initializers


@attrs.frozen(eq=False)
class SceneContext:
    """What an initializer may look at: the training cameras, the first frame's session data, and the
    scene's centre and scale (metres) derived from the calibration.

    A rig's cameras all image the fitted ``frame``. A moving camera (a monocular capture) images one pose
    per frame, so its first fit trains on the images of several frames: ``camera_frames`` then gives the
    session frame of each of ``cameras``; read a camera's image with :meth:`image`, not at ``frame``."""

    session: SessionReader
    cameras: Sequence[Camera]
    frame: int
    center: np.ndarray
    scale: float
    camera_frames: Sequence[int] = ()

    def frame_of(self, index: int) -> int:
        """The session frame whose image of ``cameras[index]`` the fit trains on."""
        return self.camera_frames[index] if self.camera_frames else self.frame

    def image(self, index: int) -> SessionFrame:
        """The image (colour, mask, depth) of ``cameras[index]`` the fit trains on."""
        return self.session.frame(self.frame_of(index), self.cameras[index].name)

    def subject_reach(self, cube: bool) -> np.ndarray | None:
        """[K] how far each cell of the subject's visual hull lies from ``center``: its largest coordinate
        (``cube``: the half side of a cube about the centre that holds it) or its length (the radius of a
        sphere); ``None`` when fewer than two training images have masks or the hull is empty. The hull is
        carved once per scene, over a cube of half side ``scale``, from the masks of the images the fit
        trains on: every initializer that sizes or checks a region reads the same one."""
        cells = self._subject_hull
        return None if cells is None else region_reach(cells, cube)

    @functools.cached_property
    def _subject_hull(self) -> np.ndarray | None:
        """[K, 3] the subject's visual hull cells less ``center`` (:meth:`subject_reach`)."""
        views = [(camera, self.image(index).mask) for index, camera in enumerate(self.cameras)]
        views = [(camera, mask) for camera, mask in views if mask is not None]
        if len(views) < 2:
            return None
        center = np.asarray(self.center, dtype=np.float64)
        cells = hull_cells(views, center, float(self.scale)) - center
        return cells if len(cells) else None


@attrs.frozen
class RegionChoice:
    """A start or pruning region an initializer grew to hold the subject (:meth:`Initializer.fit_region`):
    its parameter ``parameter`` (its own name for it, e.g. ``half_size``), which sizes ``region`` (what it
    is, e.g. "start cube's half side"), grown from the ``configured`` metres to ``chosen``, for a subject
    whose visual hull reaches ``reach`` metres from the rig centre."""

    parameter: str
    region: str
    configured: float
    chosen: float
    reach: float

    def describe(self) -> str:
        """One line for the console and run.json: what was grown, from what, to what, and why."""
        return (f"{self.region} grown from {self.configured:g} m to {self.chosen:g} m ({self.parameter}) to hold the subject's "
                f"visual hull, which reaches {self.reach:.2f} m from the rig centre")


class Initializer(ABC):
    """Places the first Gaussians or shapes the first-frame fit. Initializers compose: each hook has a
    neutral default, so one initializer can add only pruning or only a loss term.

    Two roles share this kind. A *placing* initializer (``random``, ``visual-hull``) implements
    :meth:`initial_gaussians`; a *fit shaper* (``masked``, ``sparsity-pruned``, ``in-view``,
    ``depth-supervised``) places nothing and shapes what the fit sees and keeps — its targets
    (:meth:`prepare_target`), extra loss terms (:meth:`extra_loss`) or pruning (:meth:`prune_mask`). They
    stay one kind, configured as ``[[initializer]]`` tables, because a configuration composes them in one
    ordered list and every saved run and study records them there."""

    def fit_region(self, scene: SceneContext) -> RegionChoice | None:
        """The region this initializer needs for ``scene``'s subject when its configured start or pruning
        region is too small to hold it (:meth:`SceneContext.subject_reach`), or ``None`` to keep its
        configuration (the default: no region, or one that holds the subject — never shrunk). The fit then
        builds the initializer again with ``chosen`` as its ``parameter`` and records the choice."""
        return None

    def initial_gaussians(self, scene: SceneContext, generator: torch.Generator) -> Gaussians | None:
        """Initial Gaussians, or ``None`` to leave placement to another initializer in the composition."""
        return None

    def prepare_target(self, image: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """The training target for one [H, W, 3] image given its subject mask. The image comes as its
        difference from the fit's backdrop (background colour or clean plate, :mod:`mmcsplat.training.backdrop`), so
        zeroing the outside of the subject — what masking does — leaves the backdrop there."""
        return image

    def extra_loss(self, step: int, render: RenderOutput, camera: Camera, scene: SceneContext) -> torch.Tensor | None:
        """An extra loss term for this step, or ``None``."""
        return None

    def prune_mask(self, step: int, gaussians: Gaussians, scene: SceneContext) -> torch.Tensor | None:
        """[N] bool of Gaussians to remove after this step, or ``None``."""
        return None


class DepthSource(ABC):
    """Per-camera depth maps that the ``depth-supervised`` initializer fits the rendered depth to (up to a
    learnt per-camera scale and offset): ground truth, a depth camera's maps, or a monocular estimate."""

    @abstractmethod
    def depth(self, session: SessionReader, frame: int, camera: Camera) -> np.ndarray:
        """[H, W] float32 camera-z depth in metres of ``camera`` at ``frame``, 0 where unknown; a
        ``ValueError`` naming the camera and frame when there is none."""


# -------------------------------------------------------------------------------------------- densifiers


class Densifier(ABC):
    """A densification strategy with explicit hooks around the optimiser step (as gsplat's strategies).

    ``model`` is the trainer's :class:`~mmcsplat.training.model.GaussianModel`; a densifier edits it only through
    ``model.replace`` so parameters and optimiser state stay in step."""

    @abstractmethod
    def initialize_state(self, scene_scale: float) -> dict[str, Any]:
        """Fresh running state (gradient accumulators, counters); saved in checkpoints."""

    def step_pre_backward(self, model: GaussianModel, state: dict[str, Any], step: int, render: RenderOutput) -> None:
        """Before ``loss.backward()``."""

    @abstractmethod
    def step_post_backward(self, model: GaussianModel, state: dict[str, Any], step: int, render: RenderOutput) -> None:
        """After the optimiser step: accumulate statistics (``render.means2d.grad``, ``render.radii``) and
        clone, split, prune or relocate Gaussians. ``means2d`` (and its gradient) stays on the renderer's
        device, which for a GPU backend is not the model's: move it before mixing the two."""


# ---------------------------------------------------------------------------------------------- dynamics


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
        from .render_contract import composite  # torch: not when a reader or the listing imports this module

        return composite(render, 0, self.backdrop)


@attrs.frozen(eq=False)
class TrackingContext:
    """What a dynamics method works from: the session, the first-frame fit and how it was fitted.

    ``cameras`` are the fit's training cameras, in the order of its per-camera colour terms
    (``camera_scale``/``camera_offset`` [C, 3]); ``params`` the fitted ``GAUSSIAN_PARAMETERS`` at session
    frame ``frames[0]``. Tracks frame ``k`` is session frame ``frames[k]``. ``views(t)`` gives the training
    views of session frame ``t`` whose camera holds that frame (absent ones skipped), as loss targets
    prepared like the first frame's.
    """

    session: SessionReader
    cameras: tuple[Camera, ...]
    heldout: tuple[Camera, ...]
    frames: range
    params: Mapping[str, torch.Tensor]
    camera_scale: torch.Tensor
    camera_offset: torch.Tensor
    renderer: Renderer
    settings: FitSettings
    initializers: tuple[Initializer, ...]
    #: What each training camera's renders are composited over (:mod:`mmcsplat.training.backdrop`), in ``cameras`` order.
    backdrops: tuple[torch.Tensor, ...]
    scene_center: Sequence[float]
    scene_scale: float
    #: Builds the plugins a method names in its own parameters (the ``deformation`` method's densifier),
    #: found where the pipeline's own plugins are.
    plugins: PluginBuilder
    views: Callable[[int], list[TrainingView]]
    progress: bool = True
    overwrite: bool = False
    #: Where a method logs its loss and PSNR per logged step (``curve.log(step=…, frame=…, loss=…, psnr=…)``);
    #: the pipeline writes it to ``RUN/curves.csv`` and the report plots it.
    curve: TrainingCurve = attrs.field(factory=lambda: TrainingCurve("track"))


class Dynamics(ABC):
    """Carries the first-frame Gaussians through the sequence."""

    #: Training cameras a frame must hold for the method to fit it: one that fits each frame from that frame's
    #: images alone needs two at least; one trained over the whole sequence learns from a single moving
    #: camera too. Tracking refuses, before it starts, a capture whose frames mostly hold fewer.
    cameras_per_frame: int = 1

    @property
    def reads_flow(self) -> bool:
        """Whether the method, as configured, reads the session's optical flow (``mmcsplat flow``), so that a
        study computes its sessions' flow before its cells track; none by default."""
        return False

    @abstractmethod
    def track(self, context: TrackingContext, out: Path) -> dict[str, Any]:
        """Fit every frame of ``context.frames`` from the first-frame fit ``context.params``, streaming frames
        from ``context.session`` (``context.views(t)``), and write the per-frame Gaussian states to the run
        directory ``out`` with a :class:`~mmcsplat.storage.tracks.TrackWriter` (tracks frame ``k`` is session frame
        ``context.frames[k]``; frame 0 is the first-frame fit). Returns a JSON-serialisable summary (per-frame
        losses, timings) that ``RUN/track.json`` records."""


# ----------------------------------------------------------------------------------------------- metrics


class Metric(ABC):
    """An image-quality metric between a rendered and a ground-truth image."""

    higher_is_better: bool = True

    @abstractmethod
    def __call__(self, prediction: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
        """Compare two [H, W, 3] float images in [0, 1], optionally only inside ``mask`` [H, W] bool."""


# --------------------------------------------------------------------------------------------- landmarks


def _positions(value: Any) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    array.setflags(write=False)
    return array


@attrs.frozen(eq=False)
class Landmarks:
    """Named 3D points over session frames: ``positions[k, j]`` is landmark ``names[j]`` at session frame
    ``frames[k]``, world metres (the session's calibration frame), NaN where the source has none."""

    names: tuple[str, ...] = attrs.field(converter=tuple)
    frames: np.ndarray = attrs.field(converter=lambda value: np.asarray(value, dtype=np.int64))
    positions: np.ndarray = attrs.field(converter=_positions)
    source: str = ""

    def __attrs_post_init__(self) -> None:
        expected = (len(self.frames), len(self.names), 3)
        if self.positions.shape != expected:
            raise InputError(f"landmarks from {self.source or '?'}: positions must be [frames, landmarks, 3] = {list(expected)}, "
                             f"got {list(self.positions.shape)}")
        if len(set(self.names)) != len(self.names):
            raise InputError(f"landmarks from {self.source or '?'}: duplicate names {sorted({n for n in self.names if self.names.count(n) > 1})}")

    def at(self, frame: int) -> np.ndarray:
        """[L, 3] positions at session ``frame`` (an error naming the source when it has no such frame)."""
        where = np.flatnonzero(self.frames == frame)
        if not len(where):
            raise InputError(f"landmarks from {self.source or '?'} have no session frame {frame} (they cover {self.frames.min()}–{self.frames.max()})")
        return self.positions[where[0]]


@attrs.frozen(eq=False)
class KeypointObservations:
    """2D detections of landmarks in one camera: ``pixels[k, j]`` (u, v) of landmark ``names[j]`` at session
    frame ``frames[k]`` in the session's (undistorted) image of the camera, ``confidence[k, j]`` in [0, 1]
    (0 where nothing was detected). ``edges`` are the pairs of names the source's file links in its
    skeleton (a SLEAP skeleton's edges; empty where the file declares none)."""

    camera: str
    names: tuple[str, ...] = attrs.field(converter=tuple)
    frames: np.ndarray = attrs.field(converter=lambda value: np.asarray(value, dtype=np.int64))
    pixels: np.ndarray = attrs.field(converter=_positions)
    confidence: np.ndarray = attrs.field(converter=_positions)
    edges: tuple[tuple[str, str], ...] = attrs.field(default=(), converter=lambda pairs: tuple((str(a), str(b)) for a, b in pairs))


class LandmarkSource(ABC):
    """Where named landmarks come from: a file of 3D points (TRC, CSV), 2D keypoints triangulated in the
    session's cameras, a synthetic capture's joints. The landmarks over the first frames are bound to the
    Gaussians at the fitted frame and carried through the tracks; at the frames after those they are the
    reference the carried ones are compared with."""

    #: Whether the landmarks are exact at every frame (a synthetic capture's joints): they are then bound at the
    #: fitted frame alone, where a measured source is bound from several frames so that one frame's error is
    #: outvoted (docs/landmarks.md, "Binding and carrying").
    exact: bool = False

    @abstractmethod
    def read(self, session: SessionReader, frames: Sequence[int]) -> Landmarks:
        """The landmarks at session ``frames`` (NaN where the source has none); errors name the file."""

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The 2D detections behind the landmarks, per camera, for the 2D error of carried landmarks;
        a source of 3D points has none (the default)."""
        return []
