"""Initializers of the first-frame fit: where Gaussians start, what the image loss sees, what is pruned.

They compose (a configuration lists several). `random` or `visual-hull` places the Gaussians; the fit
shapers place none: `masked` masks the targets and prunes far Gaussians, `sparsity-pruned` prunes isolated
ones, `in-view` those no training camera sees, `depth-supervised` adds a depth loss against a
`depth-source` plugin's maps. The placing ones and `masked` size their start cube or pruning sphere to the
subject's visual hull (``fit_region``) and refuse, when kept as configured, one that does not hold it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
import torch
from scipy.spatial import cKDTree

from mmcsplat.plugin_api.errors import InputError, SubjectMaskError
from mmcsplat.plugin_api.interfaces import DepthSource, Initializer, RegionChoice, SceneContext
from mmcsplat.plugin_api.parameters import at_least, finite_positive, parameter
from mmcsplat.plugin_api.registration import PluginBuilder
from mmcsplat.plugin_api.render_contract import Gaussians, RenderOutput
from mmcsplat.scene.visual_hull import REGION_SHARE, in_hull, mask_hits, mask_votes

INITIAL_OPACITY = 0.1
INITIAL_SEG = 0.5
#: A mask covering less than this share of its image holds no subject (a person or an infant at 1/4 scale covers 2–10 %).
NEARLY_EMPTY_MASK = 1e-3


def gaussians_at(points: np.ndarray, colors: np.ndarray | None, generator: torch.Generator, segmentation: np.ndarray | None = None) -> Gaussians:
    """Isotropic Gaussians at ``points`` [N, 3], sized by the mean distance to their 3 nearest neighbours
    (as 3DGS initialises from a point cloud), opacity 0.1, the given or random colours, and the given
    segmentation colours (default 0.5 each)."""
    n = len(points)
    if n == 0:
        raise InputError("no points to place Gaussians at")
    k = min(4, n)
    distances, _ = cKDTree(points).query(points, k=k)
    spacing = np.sqrt(np.mean(np.square(distances[:, 1:]), axis=1)) if k > 1 else np.full(n, 0.01)
    spacing = np.clip(spacing, 1e-4, None)
    means = torch.as_tensor(points, dtype=torch.float32)
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    log_scales = torch.as_tensor(np.log(spacing), dtype=torch.float32)[:, None].repeat(1, 3)
    opacity_logits = torch.full((n,), float(np.log(INITIAL_OPACITY / (1 - INITIAL_OPACITY))))
    colors_t = torch.rand(n, 3, generator=generator) if colors is None else torch.as_tensor(colors, dtype=torch.float32)
    features = torch.full((n, 1), INITIAL_SEG) if segmentation is None else torch.as_tensor(segmentation, dtype=torch.float32).reshape(n, 1)
    return Gaussians(means, quats, log_scales, opacity_logits, colors_t, features)


def segmentation_start(points: np.ndarray, scene: SceneContext) -> np.ndarray | None:
    """Each point's starting segmentation colour: the share of the training views that see it in which it
    falls on the subject mask (0.5 where no view sees it), clipped to [0.02, 0.98]; ``None`` without masks.

    Starting every Gaussian at 0.5 lets the segmentation loss undo an unmasked fit: its colours learn at
    1e-3 (the study's rate), far slower than opacities (5e-2), so the quickest way to render the mat with
    segmentation 0 is to make everything transparent — measured on the synthetic capture, paper-unmasked
    went transparent within 200 iterations and never fitted its training views (masked PSNR 9.4 dB)."""
    views = []
    for index, camera in enumerate(scene.cameras):
        mask = scene.image(index).mask
        if mask is None:
            return None
        views.append((camera, mask))
    seen, inside = mask_votes(np.asarray(points, dtype=np.float64), views)
    share = np.where(seen > 0, inside / np.maximum(seen, 1), INITIAL_SEG)
    return np.clip(share, 0.02, 0.98)


#: Metres a grown region holds beyond the subject's visual hull (the hull is looser than the subject already).
REGION_MARGIN = 0.1


def _region_size(reach: np.ndarray) -> float:
    """The size, rounded up to 0.1 m, of a region holding every hull cell of ``reach`` with :data:`REGION_MARGIN` to spare."""
    return float(np.ceil((reach.max() + REGION_MARGIN) * 10) / 10)


def _held_share(reach: np.ndarray, size: float) -> float:
    return float(np.mean(reach <= size))


def grown_region(scene: SceneContext, parameter: str, size: float, cube: bool) -> RegionChoice | None:
    """The region a start cube (``cube``: half side ``size``) or pruning sphere (radius ``size``) about the
    rig centre grows to when it holds less than :data:`REGION_SHARE` of the subject's visual hull (the
    region :func:`check_region` would refuse): the hull's reach plus :data:`REGION_MARGIN`, rounded up to
    0.1 m. ``None`` when it holds the subject (a region is never shrunk) or the masks give no hull."""
    reach = scene.subject_reach(cube)
    if reach is None or _held_share(reach, size) >= REGION_SHARE:
        return None
    region = "start cube's half side" if cube else "pruning sphere's radius"
    return RegionChoice(parameter, region, size, _region_size(reach), float(reach.max()))


def check_region(scene: SceneContext, initializer: str, key: str, size: float, cube: bool) -> None:
    """Refuse, before any training, a start cube (``cube``: half side ``size``) or pruning sphere (radius
    ``size``) about the rig centre that holds less than :data:`REGION_SHARE` of the subject's visual hull
    (from the training cameras' masks) — a fit that would "complete" on a cloud of floaters beside a
    subject it never covered — saying what to set. A fit grows such a region first unless told to keep it
    (``mmcsplat fit --fixed-regions``)."""
    reach = scene.subject_reach(cube)
    if reach is None:
        return
    inside = _held_share(reach, size)
    if inside < REGION_SHARE:
        shape = f"the start cube of half side {size} m" if cube else f"the pruning sphere of radius {size} m"
        center = np.round(np.asarray(scene.center, dtype=np.float64), 2).tolist()
        raise InputError(f"initializer {initializer!r}: only {inside:.0%} of the subject's visual hull (from the masks) lies inside {shape} "
                         f"about the rig centre {center}; it reaches {reach.max():.2f} m: set "
                         f"--set initializer.{initializer}.{key}={_region_size(reach):.1f} (or {key} in the configuration's [[initializer]] table)")


def _uniform_cube(count: int, center: np.ndarray, half_size: float, generator: torch.Generator) -> np.ndarray:
    offsets = (torch.rand(count, 3, generator=generator, dtype=torch.float64) * 2 - 1) * half_size
    return np.asarray(center) + offsets.numpy()


@attrs.frozen
class RandomInitializer(Initializer):
    """Gaussians uniform in a cube around the calibration centre (the study: 100 000 over a 10 m range
    unmasked; 10 000–20 000 over 1.5 m masked — range = 2 × half_size)."""

    num_points: int = parameter(10_000, doc="Gaussians placed", validator=at_least(1))
    half_size: float = parameter(0.75, doc="half the cube's side, metres", validator=finite_positive)

    def fit_region(self, scene: SceneContext) -> RegionChoice | None:
        return grown_region(scene, "half_size", self.half_size, cube=True)

    def initial_gaussians(self, scene: SceneContext, generator: torch.Generator) -> Gaussians:
        check_region(scene, "random", "half_size", self.half_size, cube=True)
        points = _uniform_cube(self.num_points, scene.center, self.half_size, generator)
        return gaussians_at(points, None, generator, segmentation_start(points, scene))


@attrs.frozen
class MaskedInitializer(Initializer):
    """The study's masking: the image loss sees images zeroed outside the subject mask, and Gaussians far
    from the calibration centre are pruned."""

    radius: float = parameter(2.0, doc="Gaussians farther than this from the calibration centre are pruned, metres", validator=finite_positive)
    every: int = parameter(100, doc="iterations between prunings", validator=at_least(1))

    def fit_region(self, scene: SceneContext) -> RegionChoice | None:
        return grown_region(scene, "radius", self.radius, cube=False)

    def prepare_target(self, image: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        if mask is None:
            raise InputError("the masked initializer needs subject masks in the session: run `mmcsplat segment` first")
        return image * mask[..., None].to(image.dtype)

    def prune_mask(self, step: int, gaussians: Gaussians, scene: SceneContext) -> torch.Tensor | None:
        if step % self.every:
            return None
        if step == 0:
            check_region(scene, "masked", "radius", self.radius, cube=False)
        center = torch.as_tensor(scene.center, dtype=gaussians.means.dtype)
        return (gaussians.means.detach() - center).norm(dim=-1) > self.radius


@attrs.frozen
class SparsityPrunedInitializer(Initializer):
    """Prunes every Gaussian whose nearest neighbour is too far (the study's "sparse" rows: 0.1 m, every
    100 iterations from 500 to 15 000)."""

    max_distance: float = parameter(0.1, doc="nearest-neighbour distance beyond which a Gaussian is pruned, metres", validator=finite_positive)
    every: int = parameter(100, doc="iterations between prunings", validator=at_least(1))
    start: int = parameter(500, doc="first iteration that prunes", validator=at_least(0))
    stop: int = parameter(15_000, doc="last iteration that prunes", validator=at_least(0))

    def prune_mask(self, step: int, gaussians: Gaussians, scene: SceneContext) -> torch.Tensor | None:
        if step < self.start or step > self.stop or step % self.every or gaussians.count < 2:
            return None
        points = gaussians.means.detach().cpu().numpy()
        distances, _ = cKDTree(points).query(points, k=2)
        return torch.as_tensor(distances[:, 1] > self.max_distance)


@attrs.frozen
class InViewInitializer(Initializer):
    """Prunes every Gaussian that no training camera sees — its centre, grown by three times its largest
    scale, projects into no training image — every ``every`` iterations from the first. Such a Gaussian
    never gets a gradient and keeps its starting opacity; near a held-out camera, outside every training
    camera's field of view, it veils that camera's whole view. A random start in a cube puts some there:
    the cube's corners point at a ring's diagonal cameras."""

    every: int = parameter(500, doc="iterations between prunings", validator=at_least(1))

    def prune_mask(self, step: int, gaussians: Gaussians, scene: SceneContext) -> torch.Tensor | None:
        if step % self.every or gaussians.count == 0:
            return None
        means = gaussians.means.detach().double().cpu().numpy()
        reach = 3 * np.exp(gaussians.log_scales.detach().double().cpu().numpy()).max(axis=1)
        seen = np.zeros(len(means), dtype=bool)
        for camera in scene.cameras:
            depth = (means @ camera.R.T + camera.t)[:, 2]
            front = depth > 1e-6
            pixels = camera.project(means[front])
            margin = reach[front] * camera.K[0, 0] / depth[front]
            inside = np.all((pixels > -margin[:, None]) & (pixels < np.array([camera.width, camera.height]) + margin[:, None]), axis=1)
            seen[np.flatnonzero(front)[inside]] = True
        return torch.as_tensor(~seen)


@attrs.frozen
class VisualHullInitializer(Initializer):
    """Gaussians sampled inside the intersection of every training camera's mask cone (space carving),
    coloured from the views: a start on the subject's surface volume rather than in a cube. Candidates are
    drawn in a cube around the calibration centre and kept where nearly every view that sees them agrees."""

    num_points: int = parameter(10_000, doc="Gaussians placed", validator=at_least(1))
    half_size: float = parameter(0.75, doc="half the side of the cube candidates are drawn in, metres", validator=finite_positive)
    tolerance: int = parameter(0, doc="views that see a candidate outside their mask and still keep it", validator=at_least(0))
    max_rounds: int = parameter(50, doc="rounds of candidate draws before giving up", validator=at_least(1))

    def fit_region(self, scene: SceneContext) -> RegionChoice | None:
        return grown_region(scene, "half_size", self.half_size, cube=True)

    def initial_gaussians(self, scene: SceneContext, generator: torch.Generator) -> Gaussians:
        views = []
        for index, camera in enumerate(scene.cameras):
            frame = scene.image(index)
            if frame.mask is None:
                raise InputError(f"visual-hull initializer: camera {camera.name!r} has no mask at frame {scene.frame_of(index)}: "
                                 "run `mmcsplat segment` first")
            views.append((camera, frame.mask, frame.rgb))
        check_region(scene, "visual-hull", "half_size", self.half_size, cube=True)
        kept_points: list[np.ndarray] = []
        kept_colors: list[np.ndarray] = []
        total = 0
        batch = max(4 * self.num_points, 20_000)
        for _ in range(self.max_rounds):
            points = _uniform_cube(batch, scene.center, self.half_size, generator)
            inside, colors = self._carve(points, views)
            kept_points.append(points[inside])
            kept_colors.append(colors[inside])
            total += int(inside.sum())
            if total >= self.num_points:
                break
        if total == 0:
            cover = {camera.name: float(np.mean(mask > 0.5)) for camera, mask, _ in views}
            faint = [f"{name} ({share:.3%} of its pixels)" for name, share in cover.items() if share < NEARLY_EMPTY_MASK]
            why = f"the masks of {', '.join(faint)} are nearly empty" if faint else "are the masks and calibration consistent?"
            raise SubjectMaskError(f"visual-hull initializer: no point lies inside every view's mask at frame {scene.frame}: {why}")
        points = np.concatenate(kept_points)[: self.num_points]
        colors = np.concatenate(kept_colors)[: self.num_points]
        return gaussians_at(points, colors, generator, segmentation_start(points, scene))

    def _carve(self, points: np.ndarray, views) -> tuple[np.ndarray, np.ndarray]:
        color_sum = np.zeros((len(points), 3))
        seen = np.zeros(len(points), dtype=int)
        on_masks = np.zeros(len(points), dtype=int)
        for (_, _, rgb), (pixels, sees, on_mask) in zip(views, mask_hits(points, [(camera, mask) for camera, mask, _ in views])):
            seen += sees
            on_masks += on_mask
            color_sum[on_mask] += rgb[pixels[on_mask, 1], pixels[on_mask, 0]] / 255.0
        inside = in_hull(seen, on_masks, self.tolerance)
        colors = color_sum / np.maximum(on_masks, 1)[:, None]
        return inside, colors


@attrs.define(eq=False)  # identity equality and hash, as before: it holds tensors and an optimiser
class DepthSupervisedInitializer(Initializer):
    """An L1 loss between rendered depth and a per-camera depth map, with a learnable per-camera scale and
    offset (monocular depth is only defined up to them). The maps come from a ``depth-source`` plugin,
    built by the registry that builds this initializer; pixels without depth are ignored."""

    weight: float = parameter(0.1, doc="weight of the depth loss", validator=at_least(0))
    lr: float = parameter(1e-3, doc="learning rate of each camera's depth scale and offset", validator=finite_positive)
    source: str | Mapping[str, Any] = parameter(
        "session", doc='the depth-source plugin: its name, or a table of name and parameters ({ name = "session", noise = 0.05 })')
    registry: PluginBuilder = attrs.field(kw_only=True, repr=False)
    depth_source: DepthSource = attrs.field(init=False, repr=False)
    _maps: dict[str, torch.Tensor] = attrs.field(init=False, factory=dict, repr=False)
    _affine: dict[str, torch.Tensor] = attrs.field(init=False, factory=dict, repr=False)
    _optimizer: torch.optim.Adam | None = attrs.field(init=False, default=None, repr=False)

    def __attrs_post_init__(self) -> None:
        options = {"name": self.source} if isinstance(self.source, str) else dict(self.source)
        name = options.pop("name", None)
        if not isinstance(name, str):
            raise InputError(f"source must be a depth-source name or a table with a 'name', got {self.source!r}")
        self.depth_source = self.registry.create("depth-source", name, **options)

    def _load(self, scene: SceneContext) -> None:
        """Read every training camera's depth map once; one Adam over all scale/offsets."""
        for index, camera in enumerate(scene.cameras):
            try:
                depth = self.depth_source.depth(scene.session, scene.frame_of(index), camera)
            except ValueError as error:
                raise InputError(f"depth-supervised initializer: {error}") from error
            self._maps[camera.name] = torch.tensor(np.asarray(depth, dtype=np.float32))  # a copy: the source's may be shared
            self._affine[camera.name] = torch.tensor([1.0, 0.0], requires_grad=True)
        self._optimizer = torch.optim.Adam(list(self._affine.values()), lr=self.lr)

    def extra_loss(self, step: int, render: RenderOutput, camera, scene: SceneContext) -> torch.Tensor:
        if self._optimizer is None:
            self._load(scene)
        else:  # the previous iteration's backward filled the scale/offset gradients
            self._optimizer.step()
            self._optimizer.zero_grad(set_to_none=True)
        target = self._maps[camera.name]
        scale, offset = self._affine[camera.name]
        valid = (target > 0) & (render.alpha[0].detach() > 0.5)
        if not valid.any():
            return render.depth.sum() * 0.0
        predicted = render.depth[0][valid] * scale + offset
        return self.weight * (predicted - target[valid]).abs().mean()
