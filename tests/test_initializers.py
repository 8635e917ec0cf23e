"""The built-in initializers (random, masked, visual-hull, sparsity-pruned, depth-supervised) on the tiny
fitting scene: a five-camera 48 × 36 session of known Gaussians (tests/fitting_scene.py), each built by
name through the registry and shown the scene as a first-frame fit shows it."""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch
from fitting_scene import scene_context, single_precision, subject, write_session
from scipy.spatial import cKDTree

from mmcsplat import Registration, hookimpl
from mmcsplat.configuration.registry import PluginError, Registry, UnknownPluginError, default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import DepthSource, RegionChoice
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.plugins.initializers import segmentation_start
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.views import load_view


def initializer(name: str, registry: Registry | None = None, **params):
    """The initializer ``name``, built as a configuration's [[initializer]] table builds it."""
    return (registry or default_registry()).create("initializer", name, **params)


def seeded(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The fitting scene's first frame, with masks and ground-truth depth."""
    return scene_context(SessionReader(write_session(tmp_path_factory.mktemp("scene") / "scene.zarr")))


@pytest.fixture(scope="module")
def bare_scene(tmp_path_factory):
    """The fitting scene recorded without masks or depth maps."""
    path = write_session(tmp_path_factory.mktemp("bare") / "bare.zarr", masks=False, depth=False)
    return scene_context(SessionReader(path))


def points_at(means) -> Gaussians:
    """Gaussians at ``means`` [N, 3] (only their positions matter to pruning)."""
    means = torch.as_tensor(np.asarray(means), dtype=torch.float32)
    n = len(means)
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1
    return Gaussians(means, quats, torch.full((n, 3), -4.0), torch.zeros(n), torch.full((n, 3), 0.5), torch.full((n, 1), 0.5))


def hits(points: np.ndarray, scene):
    """Per training camera, by plain projection: (its frame, nearest pixels [N, 2], [N] bool in front of it
    and inside its image, [N] bool seen there on the mask)."""
    points = np.asarray(points, dtype=np.float64)
    for camera in scene.cameras:
        frame = scene.session.frame(scene.frame, camera.name)
        pixels = np.round(camera.project(points)).astype(int)
        seen = ((points @ camera.R.T + camera.t)[:, 2] > 0) & np.all((pixels >= 0) & (pixels < [camera.width, camera.height]), axis=1)
        on_mask = seen.copy()
        on_mask[seen] = frame.mask[pixels[seen, 1], pixels[seen, 0]]
        yield frame, pixels, seen, on_mask


def mask_votes_of(points: np.ndarray, scene) -> tuple[np.ndarray, np.ndarray]:
    """(seen, on mask) [N] counts of ``points`` over the scene's training views."""
    votes = [(seen, on_mask) for _, _, seen, on_mask in hits(points, scene)]
    return sum(seen.astype(int) for seen, _ in votes), sum(on_mask.astype(int) for _, on_mask in votes)


# ------------------------------------------------------------------------------------------------ random


def test_random_places_the_requested_count_inside_the_cube_reproducibly(scene):
    placed = initializer("random", num_points=400, half_size=0.3).initial_gaussians(scene, seeded(0))
    assert placed.count == 400
    offsets = placed.means.numpy() - scene.center
    assert np.abs(offsets).max() <= 0.3 + 1e-6
    assert np.abs(offsets).max() > 0.28  # the whole cube, not a corner of it
    again = initializer("random", num_points=400, half_size=0.3).initial_gaussians(scene, seeded(0))
    other = initializer("random", num_points=400, half_size=0.3).initial_gaussians(scene, seeded(1))
    torch.testing.assert_close(again.means, placed.means, rtol=0, atol=0)
    torch.testing.assert_close(again.colors, placed.colors, rtol=0, atol=0)
    assert not torch.allclose(other.means, placed.means)


@pytest.mark.parametrize("params, message", [
    ({"num_points": 0}, "num_points must be ≥ 1, got 0"), ({"num_points": -5}, "num_points must be ≥ 1, got -5"),
    ({"half_size": 0.0}, "half_size must be a finite number > 0, got 0.0"), ({"half_size": float("nan")}, "half_size must be a finite number > 0"),
    ({"num_points": 10.5}, "parameter 'num_points' must be an integer, got 10.5"), ({"half_size": "big"}, "parameter 'half_size' must be a number"),
    ({"halfsize": 1.0}, "unknown parameter.*halfsize; known: num_points, half_size"),
])
def test_random_rejects_bad_parameters_naming_itself(params, message):
    with pytest.raises(InputError, match=f"initializer 'random': {message}"):
        initializer("random", **params)


@pytest.mark.parametrize("name, params, message", [
    ("masked", {"radius": 0.0}, "radius must be a finite number > 0, got 0.0"),
    ("masked", {"every": "often"}, "parameter 'every' must be an integer, got 'often'"),
    ("sparsity-pruned", {"every": 0}, "every must be ≥ 1, got 0"),
    ("sparsity-pruned", {"max_distance": True}, "parameter 'max_distance' must be a number, got True"),
    ("in-view", {"every": 0}, "every must be ≥ 1, got 0"),
    ("in-view", {"every": 2.0}, "parameter 'every' must be an integer, got 2.0"),
    ("visual-hull", {"tolerance": -1}, "tolerance must be ≥ 0, got -1"),
    ("visual-hull", {"max_rounds": 0}, "max_rounds must be ≥ 1, got 0"),
    ("visual-hull", {"num_points": "many"}, "parameter 'num_points' must be an integer, got 'many'"),
    ("depth-supervised", {"weight": -0.1}, "weight must be ≥ 0, got -0.1"),
    ("depth-supervised", {"lr": 0.0}, "lr must be a finite number > 0, got 0.0"),
    ("depth-supervised", {"source": 3}, "parameter 'source' must be a string or a table, got 3"),
])
def test_initializers_refuse_out_of_range_and_mistyped_parameters_naming_themselves(name, params, message):
    with pytest.raises(InputError, match=f"initializer '{name}': {message}"):
        initializer(name, **params)


@pytest.mark.parametrize("params, message", [
    ({"noise": -0.1}, "noise must be ≥ 0, got -0.1"), ({"noise": float("nan")}, "noise must be ≥ 0, got nan"),
    ({"noise": "loud"}, "parameter 'noise' must be a number, got 'loud'"), ({"seed": 1.5}, "parameter 'seed' must be an integer, got 1.5"),
])
def test_the_session_depth_source_refuses_bad_parameters_naming_itself(params, message):
    with pytest.raises(InputError, match=f"depth-source 'session': {message}"):
        default_registry().create("depth-source", "session", **params)
    with pytest.raises(InputError, match=f"initializer 'depth-supervised': depth-source 'session': {message}"):
        initializer("depth-supervised", source={"name": "session", **params})


def test_random_starts_segmentation_on_the_subject_high_and_off_it_low(scene):
    placed = initializer("random", num_points=500, half_size=0.25).initial_gaussians(scene, seeded(0))
    segmentation = placed.features[:, 0].numpy()
    np.testing.assert_allclose(segmentation, segmentation_start(placed.means.numpy(), scene), atol=1e-7)
    distance, _ = cKDTree(subject().means.numpy()).query(placed.means.numpy())
    near, far = distance < 0.02, distance > 0.15
    assert near.sum() >= 5 and far.sum() >= 50
    assert segmentation[near].min() >= 0.9
    # A point 15 cm off the subject can still lie on a ray through it in one or two of the four views.
    assert segmentation[far].max() <= 0.5 and np.median(segmentation[far]) <= 0.25


def test_segmentation_start_is_the_clipped_share_of_views_seeing_a_point_on_the_mask(scene):
    on_subject = subject().means.numpy()
    np.testing.assert_array_equal(segmentation_start(on_subject, scene), 0.98)  # on every mask: clipped from 1
    above_and_below = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, -0.3]])
    np.testing.assert_array_equal(segmentation_start(above_and_below, scene), 0.02)  # on none: clipped from 0
    out_of_sight = np.array([[0.0, 0.0, 5.0], [10.0, 10.0, 0.0]])
    assert not mask_votes_of(out_of_sight, scene)[0].any()
    np.testing.assert_array_equal(segmentation_start(out_of_sight, scene), 0.5)
    mixed = np.array([[0.0, 0.3, 0.0]])
    seen, on_mask = mask_votes_of(mixed, scene)
    assert 0 < on_mask[0] < seen[0]
    np.testing.assert_allclose(segmentation_start(mixed, scene), on_mask / seen)


def test_without_masks_segmentation_starts_neutral(bare_scene):
    assert segmentation_start(np.zeros((3, 3)), bare_scene) is None
    placed = initializer("random", num_points=50, half_size=0.25).initial_gaussians(bare_scene, seeded(0))
    np.testing.assert_array_equal(placed.features.numpy(), 0.5)


# ------------------------------------------------------------------------------------------------ masked


def test_masked_target_is_zero_outside_the_mask_and_the_image_inside():
    image = torch.rand(6, 8, 3, generator=seeded(0)) + 0.1
    mask = torch.zeros(6, 8, dtype=torch.bool)
    mask[1:4, 2:7] = True
    target = initializer("masked").prepare_target(image, mask)
    torch.testing.assert_close(target[mask], image[mask], rtol=0, atol=0)
    assert not target[~mask].any()


def test_masked_needs_masks_in_the_session(bare_scene):
    camera = bare_scene.cameras[0]
    with pytest.raises(ValueError, match="masked initializer needs subject masks.*mmcsplat segment"):
        load_view(bare_scene.session, 0, camera, 0, [initializer("masked")], torch.zeros(3))


def test_masked_prunes_exactly_the_gaussians_beyond_the_radius_on_its_grid(scene):
    directions = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [0.6, 0.8, 0]])
    factors = np.array([0.5, 0.99, 1.01, 3.0])
    gaussians = points_at(scene.center + 0.4 * factors[:, None] * directions)
    masked = initializer("masked", radius=0.4, every=25)
    for step in (0, 25, 100):
        np.testing.assert_array_equal(masked.prune_mask(step, gaussians, scene).numpy(), factors > 1)
    for step in (1, 24, 60):
        assert masked.prune_mask(step, gaussians, scene) is None


def test_in_view_prunes_the_gaussians_no_training_camera_sees(scene):
    camera = scene.cameras[0]
    # 5 px left of a training image, 0.3 m from its camera: a 10 cm Gaussian reaches into it (40 px), a
    # 1 cm one does not (4 px).
    beside = camera.R.T @ (0.3 * np.array([(-5 - camera.K[0, 2]) / camera.K[0, 0], 0.0, 1.0]) - camera.t)
    behind_heldout = 1.3 * scene.session.camera("cam_0").center  # outside every training camera's view
    gaussians = points_at([scene.center, behind_heldout, beside, beside])
    gaussians = Gaussians(gaussians.means, gaussians.quats, torch.log(torch.tensor([[0.02] * 3, [0.02] * 3, [0.1] * 3, [0.01] * 3])),
                          gaussians.opacity_logits, gaussians.colors, gaussians.features)
    seen_centres = sum(seen for _, _, seen, _ in hits(gaussians.means.numpy(), scene))
    assert seen_centres[0] > 0 and not seen_centres[1:].any()
    in_view = initializer("in-view", every=50)
    np.testing.assert_array_equal(in_view.prune_mask(0, gaussians, scene).numpy(), [False, True, False, True])
    assert in_view.prune_mask(49, gaussians, scene) is None and in_view.prune_mask(100, gaussians, scene) is not None
    with pytest.raises(ValueError, match="every must be"):
        initializer("in-view", every=0)


# ------------------------------------------------------------------------------------------- visual hull


@pytest.mark.parametrize("tolerance", [0, 1])
def test_visual_hull_points_lie_inside_the_hull_and_take_the_views_colours(scene, tolerance):
    placed = initializer("visual-hull", num_points=300, half_size=0.25, tolerance=tolerance).initial_gaussians(scene, seeded(0))
    assert placed.count == 300
    points = placed.means.numpy().astype(np.float64)
    seen, on_mask = mask_votes_of(points, scene)
    assert (on_mask > 0).all() and (seen - on_mask <= tolerance).all()
    if tolerance:
        assert (seen - on_mask == tolerance).any()  # the tolerance widens the hull
    # Each colour is the mean of the images' pixels the point projects to on a mask.
    total, count = np.zeros((len(points), 3)), np.zeros(len(points))
    for frame, pixels, _, on_mask in hits(points, scene):
        total[on_mask] += frame.rgb[pixels[on_mask, 1], pixels[on_mask, 0]] / 255.0
        count += on_mask
    np.testing.assert_allclose(placed.colors.numpy(), total / count[:, None], atol=1e-6)
    assert placed.colors.std(dim=0).min() > 0.05  # the subject's colours, not a constant
    np.testing.assert_allclose(placed.features.numpy()[:, 0], segmentation_start(points, scene), atol=1e-7)


def test_visual_hull_needs_every_training_camera_masked(bare_scene):
    with pytest.raises(ValueError, match=r"visual-hull initializer: camera 'cam_1' has no mask at frame 0.*mmcsplat segment"):
        initializer("visual-hull", num_points=50).initial_gaussians(bare_scene, seeded(0))


def test_visual_hull_of_inconsistent_masks_is_empty_and_an_error(tmp_path):
    # cam_2's mask is empty while the others see the subject: no point is on every mask.
    scene = scene_context(SessionReader(write_session(tmp_path / "blind.zarr", blank=("cam_2",))))
    hull = initializer("visual-hull", num_points=50, half_size=0.25, max_rounds=2)
    with pytest.raises(ValueError, match=r"no point lies inside every view's mask at frame 0: the masks of cam_2 \(0\.000% of its pixels\) are nearly empty"):
        hull.initial_gaussians(scene, seeded(0))


# ------------------------------------------------------------------------------------------ sparsity


def test_sparsity_prunes_exactly_the_isolated_gaussians_inside_its_window(scene):
    cluster = [[0.0, 0, 0], [0.05, 0, 0], [0.05, 0.05, 0], [0.0, 0.06, 0.02]]
    pair = [[1.0, 1.0, 1.0], [1.08, 1.0, 1.0]]  # each other's neighbour, 8 cm apart
    loners = [[-1.0, 0, 0], [0.0, 0, 0.5]]  # ≥ 0.5 m from anything
    gaussians = points_at(cluster + pair + loners)
    sparse = initializer("sparsity-pruned", max_distance=0.1, every=50, start=100, stop=300)
    expected = np.array([False] * 6 + [True] * 2)
    for step in (100, 150, 300):
        np.testing.assert_array_equal(sparse.prune_mask(step, gaussians, scene).numpy(), expected)
    for step in (0, 50, 120, 301, 350):
        assert sparse.prune_mask(step, gaussians, scene) is None
    tighter = initializer("sparsity-pruned", max_distance=0.07, every=50, start=100, stop=300)
    np.testing.assert_array_equal(tighter.prune_mask(100, gaussians, scene).numpy(), [False] * 4 + [True] * 4)


# ------------------------------------------------------------------------------------- depth supervision


def first_view_render(scene, gaussians: Gaussians):
    """(the scene's first training camera, a torch-reference render of ``gaussians`` in it)."""
    camera = scene.cameras[0]
    return camera, default_registry().create("renderer", "torch-reference").render(gaussians, RenderCameras.from_cameras([camera]))


def depth_loss(scene, gaussians: Gaussians, registry: Registry | None = None, **params) -> torch.Tensor:
    """A fresh depth-supervised initializer's loss for a render of ``gaussians`` in the first training camera."""
    camera, render = first_view_render(scene, gaussians)
    return initializer("depth-supervised", registry, **params).extra_loss(0, render, camera, scene)


def shifted(gaussians: Gaussians, by: float) -> Gaussians:
    return Gaussians(gaussians.means + torch.tensor([by, 0.0, 0.0]), *(getattr(gaussians, f) for f in ("quats", "log_scales", "opacity_logits", "colors", "features")))


def test_depth_loss_vanishes_on_the_truth_and_pulls_a_shifted_subject(scene):
    truth = single_precision(subject())
    assert depth_loss(scene, truth).item() < 1e-4
    means = truth.means.clone().requires_grad_(True)
    moved = shifted(Gaussians(means, *(getattr(truth, f) for f in ("quats", "log_scales", "opacity_logits", "colors", "features"))), 0.03)
    loss = depth_loss(scene, moved)
    assert loss.item() > 1e-3
    loss.backward()
    assert means.grad is not None and torch.isfinite(means.grad).all() and means.grad.abs().sum() > 0


def test_depth_noise_perturbs_the_maps_reproducibly(scene):
    truth = single_precision(subject())
    clean = depth_loss(scene, truth).item()
    noisy = depth_loss(scene, truth, source={"name": "session", "noise": 0.05, "seed": 3}).item()
    assert noisy > 10 * max(clean, 1e-6)
    assert depth_loss(scene, truth, source={"name": "session", "noise": 0.05, "seed": 3}).item() == noisy
    assert depth_loss(scene, truth, source={"name": "session", "noise": 0.05, "seed": 4}).item() != noisy


def test_depth_supervision_needs_depth_maps(bare_scene):
    with pytest.raises(ValueError, match="depth-supervised initializer: session depth source: camera 'cam_1' has no depth map at frame 0"):
        depth_loss(bare_scene, single_precision(subject()))


class DoubledDepth(DepthSource):
    """A third-party depth source for the test below: the session's depth, twice over."""

    def depth(self, session, frame, camera):
        return 2 * session.frame(frame, camera.name).depth


def test_the_depth_source_is_a_plugin_chosen_by_name(scene):
    """A depth source another distribution registers feeds the loss by name, found in the registry that
    builds the initializer; bad choices are named."""
    plugin = types.ModuleType("doubled_depth")
    plugin.mmcsplat_depth_sources = hookimpl(lambda: [Registration("doubled", f"{__name__}:DoubledDepth")])
    extended = Registry([("doubled", "test-dist", plugin)])
    truth = single_precision(subject())
    assert depth_loss(scene, truth, extended).item() < 1e-4
    assert depth_loss(scene, truth, extended, source="doubled").item() > 0.05  # |z − 2z| ≈ 1.4 m, weight 0.1
    with pytest.raises(UnknownPluginError, match=r"unknown depth-source 'monocular'; registered: doubled, session"):
        initializer("depth-supervised", extended, source="monocular")
    with pytest.raises(ValueError, match="source must be a depth-source name or a table with a 'name'"):
        initializer("depth-supervised", source={"noise": 0.1})
    with pytest.raises(InputError, match=r"depth-source 'session': unknown parameter\(s\) blur; known: noise, seed"):
        initializer("depth-supervised", source={"name": "session", "blur": 2})
    with pytest.raises(PluginError, match=r"initializer 'depth-supervised': 'registry' is not a configuration parameter"):
        default_registry().create("initializer", "depth-supervised", registry="elsewhere")


def test_depth_maps_are_copied_from_the_sessions_read_only_frames(scene):
    # Wrapping a cached frame would share it with every other reader (and make torch warn: it is read-only).
    camera, render = first_view_render(scene, single_precision(subject()))
    supervisor = initializer("depth-supervised")
    supervisor.extra_loss(0, render, camera, scene)
    assert not np.shares_memory(supervisor._maps[camera.name].numpy(), scene.session.frame(scene.frame, camera.name).depth)


# ------------------------------------------------------------------------------------------- regions


def use_region(plugin, scene) -> None:
    """What checks a plugin's region: placing Gaussians, or the masked initializer's first pruning."""
    if hasattr(plugin, "radius"):
        plugin.prune_mask(0, points_at(np.array([scene.center])), scene)
    else:
        plugin.initial_gaussians(scene, seeded(0))


@pytest.mark.parametrize(("name", "params", "message"), [
    ("random", {"half_size": 0.05}, r"initializer 'random': only \d+% of the subject's visual hull \(from the masks\) lies inside the start cube"),
    ("visual-hull", {"half_size": 0.05}, r"it reaches 0\.\d\d m: set --set initializer\.visual-hull\.half_size=0\.\d"),
    ("masked", {"radius": 0.05}, r"inside the pruning sphere of radius 0\.05 m .* set --set initializer\.masked\.radius=0\.\d"),
])
def test_a_region_too_small_for_the_subject_is_refused_before_fitting_saying_what_to_set(scene, name, params, message):
    with pytest.raises(InputError, match=message):
        use_region(initializer(name, **params), scene)
    use_region(initializer(name), scene)  # the defaults hold the test scene's subject


REGIONS = [("random", "half_size", "start cube's half side", True), ("visual-hull", "half_size", "start cube's half side", True),
           ("masked", "radius", "pruning sphere's radius", False)]


@pytest.mark.parametrize(("name", "parameter", "region", "cube"), REGIONS)
def test_a_region_too_small_for_the_subject_grows_to_the_hull_plus_10_cm_the_value_its_refusal_names(scene, name, parameter, region, cube):
    reach = scene.subject_reach(cube)
    choice = initializer(name, **{parameter: 0.05}).fit_region(scene)
    needed = float(np.ceil((reach.max() + 0.1) * 10) / 10)
    assert choice == RegionChoice(parameter, region, 0.05, needed, float(reach.max()))
    with pytest.raises(InputError, match=rf"set --set initializer\.{name}\.{parameter}={needed:.1f} "):
        use_region(initializer(name, **{parameter: 0.05}), scene)
    grown = initializer(name, **{parameter: choice.chosen})
    assert grown.fit_region(scene) is None  # it holds the subject now: accepted, and not grown again
    use_region(grown, scene)
    assert initializer(name).fit_region(scene) is None  # the defaults hold the test scene's subject
    assert initializer(name, **{parameter: 50.0}).fit_region(scene) is None  # never shrunk


def test_initializers_without_a_region_or_a_hull_keep_their_configuration(scene, bare_scene):
    for name in ("sparsity-pruned", "in-view", "depth-supervised"):  # the neutral default
        assert initializer(name).fit_region(scene) is None
    assert bare_scene.subject_reach(cube=True) is None  # no masks, no hull: nothing to size a region by
    assert initializer("random", half_size=0.05).fit_region(bare_scene) is None
