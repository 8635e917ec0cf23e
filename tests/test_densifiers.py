"""The built-in densifiers (default, budget) on the tiny fitting scene (tests/fitting_scene.py): a few
Gaussians in front of one training camera, trained as a first-frame fit trains them — a torch-reference
render, a loss against the camera's image, backward, the optimiser step, then the densifier's hooks — so
the screen-space gradients the default densifier thresholds are real."""

from __future__ import annotations

import pytest
import torch
from fitting_scene import scene_context, write_session

from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.scene.gaussian_table import GAUSSIAN_PARAMETERS
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.model import GaussianModel, LearningRates

SMALL, LARGE = 0.005, 0.05  # metres: below and above size_fraction (0.01) × the scene scale (1.44 m)
IN_VIEW = [[-0.1, 0.0, 0.0], [0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [-0.1, 0.08, 0.0], [0.0, 0.08, 0.0], [0.1, 0.08, 0.0]]
OUT_OF_VIEW = [[0.0, 0.0, 5.0], [5.0, 5.0, 0.0]]  # no training camera sees them: no gradient


def densifier(name: str, **params):
    """The built-in densifier ``name``, built as a configuration's [densifier] table builds it."""
    return default_registry().create("densifier", name, **params)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return scene_context(SessionReader(write_session(tmp_path_factory.mktemp("scene") / "scene.zarr")))


def model_of(scene, means, scales, opacities) -> GaussianModel:
    """A trainable model of isotropic Gaussians with distinct random colours (which tell them apart)."""
    means = torch.as_tensor(means, dtype=torch.float32)
    n = len(means)
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1
    log_scales = torch.as_tensor(scales, dtype=torch.float32).log()[:, None].repeat(1, 3)
    opacity_logits = torch.logit(torch.as_tensor(opacities, dtype=torch.float32))
    colors = torch.rand(n, 3, generator=torch.Generator().manual_seed(0))
    gaussians = Gaussians(means, quats, log_scales, opacity_logits, colors, torch.full((n, 1), 0.5))
    return GaussianModel(gaussians, tuple(camera.name for camera in scene.cameras), LearningRates(), scene.scale)


def fit_step(scene, model: GaussianModel, densifier, state: dict, step: int) -> dict[str, torch.Tensor]:
    """One fit iteration on the scene's first training camera, in FirstFrameFit's order; returns the
    parameters as the densifier's post-backward hook found them."""
    camera = scene.cameras[0]
    render = default_registry().create("renderer", "torch-reference").render(model.gaussians(), RenderCameras.from_cameras([camera]))
    target = torch.from_numpy(scene.session.frame(scene.frame, camera.name).rgb / 255.0).float()
    loss = (render.rgb[0] - target).abs().mean()
    densifier.step_pre_backward(model, state, step, render)
    loss.backward()
    model.step()
    seen = {name: tensor.detach().clone() for name, tensor in model.params.items()}
    densifier.step_post_backward(model, state, step, render)
    return seen


def rows_of(model: GaussianModel, before: dict[str, torch.Tensor], index: int) -> dict[str, torch.Tensor]:
    """The model's current rows descended from Gaussian ``index`` of ``before`` (the same colour)."""
    same = (model.params["color_logits"].detach() == before["color_logits"][index]).all(dim=-1)
    return {name: tensor.detach()[same] for name, tensor in model.params.items()}


def assert_trainable(scene, model: GaussianModel) -> None:
    """Every parameter is its optimiser's, with Adam moments of its shape, and a further iteration runs."""
    for name in GAUSSIAN_PARAMETERS:
        optimizer = model.optimizers[name]
        assert optimizer.param_groups[0]["params"] == [model.params[name]]
        for moments in optimizer.state.get(model.params[name], {}).values():
            if moments.dim():
                assert moments.shape == model.params[name].shape, name
    fit_step(scene, model, densifier("default", start=10**6), {"grad_sum": None, "count": None, "scene_scale": scene.scale}, 1)
    assert all(torch.isfinite(tensor).all() for tensor in model.params.values())


# --------------------------------------------------------------------------------------------- default


def test_gaussians_with_a_large_screen_gradient_are_cloned_when_small_and_split_when_large(scene):
    scales = [SMALL] * 3 + [LARGE] * 3 + [SMALL] * 2
    model = model_of(scene, IN_VIEW + OUT_OF_VIEW, scales, [0.5] * 8)
    default = densifier("default", start=0, every=10, split_factor=1.6)
    before = fit_step(scene, model, default, default.initialize_state(scene.scale), 0)
    # Three clones, three parents replaced by two children each; nothing happens to the unseen pair.
    assert model.count == 8 + 3 + 3
    for small in range(3):
        rows = rows_of(model, before, small)
        assert len(rows["means"]) == 2
        for name, values in rows.items():
            torch.testing.assert_close(values, before[name][small].expand_as(values), rtol=0, atol=0)
    for large in range(3, 6):
        rows = rows_of(model, before, large)
        assert len(rows["means"]) == 2 and not (rows["means"] == before["means"][large]).all(dim=-1).any()
        assert ((rows["means"] - before["means"][large]).norm(dim=-1) < 4 * LARGE).all()
        torch.testing.assert_close(rows["log_scales"], (before["log_scales"][large] - torch.log(torch.tensor(1.6))).expand(2, 3))
    for unseen in range(6, 8):
        assert len(rows_of(model, before, unseen)["means"]) == 1
    assert_trainable(scene, model)


def test_nothing_grows_below_the_gradient_threshold(scene):
    model = model_of(scene, IN_VIEW, [SMALL] * 3 + [LARGE] * 3, [0.5] * 6)
    default = densifier("default", grad_threshold=1.0, start=0, every=10)
    before = fit_step(scene, model, default, default.initialize_state(scene.scale), 0)
    torch.testing.assert_close(model.params["means"].detach(), before["means"], rtol=0, atol=0)


@pytest.mark.parametrize("grad_threshold, descendants", [(1.0, [1, 0, 1, 0]), (1e-9, [2, 0, 2, 0])], ids=["still", "growing"])
def test_faint_and_oversized_gaussians_are_pruned(scene, grad_threshold, descendants):
    # Growing, the faint and the oversized Gaussians (which have gradients too: the faint one is drawn, above
    # the renderer's 1/255 alpha floor) leave no clone or children.
    model = model_of(scene, IN_VIEW[:4], [SMALL, SMALL, LARGE, 0.3], [0.5, 0.01, 0.5, 0.5])
    default = densifier("default", grad_threshold=grad_threshold, start=0, every=10, prune_opacity=0.02, prune_size_fraction=0.1)
    before = fit_step(scene, model, default, default.initialize_state(scene.scale), 0)
    assert [len(rows_of(model, before, index)["means"]) for index in range(4)] == descendants
    assert_trainable(scene, model)


def test_nothing_changes_outside_the_window_or_off_the_grid(scene):
    # Every step would clone a Gaussian and prune the faint one, were it a densification step.
    model = model_of(scene, IN_VIEW[:2], [SMALL, SMALL], [0.5, 0.001])
    default = densifier("default", start=10, stop=20, every=5, reset_every=1000)
    state = default.initialize_state(scene.scale)
    for step in (0, 5, 9, 11, 20, 25):
        fit_step(scene, model, default, state, step)
        assert model.count == 2, step
    before = fit_step(scene, model, default, state, 10)
    assert [len(rows_of(model, before, index)["means"]) for index in range(2)] == [2, 0]  # cloned, pruned


def test_opacity_reset_caps_opacities_at_its_interval(scene):
    model = model_of(scene, IN_VIEW[:3], [SMALL] * 3, [0.5, 0.9, 0.003])
    default = densifier("default", start=10**6, stop=50, reset_every=7, reset_opacity=0.01)
    state = default.initialize_state(scene.scale)
    for step in (0, 6):
        fit_step(scene, model, default, state, step)
        assert torch.sigmoid(model.params["opacity_logits"].detach())[:2].min() > 0.4
    before = fit_step(scene, model, default, state, 7)
    opacity = torch.sigmoid(model.params["opacity_logits"].detach())
    torch.testing.assert_close(opacity[:2], torch.full((2,), 0.01))
    torch.testing.assert_close(opacity[2], torch.sigmoid(before["opacity_logits"][2]), rtol=0, atol=0)
    moments = model.optimizers["opacity_logits"].state[model.params["opacity_logits"]]
    assert not moments["exp_avg"].any() and not moments["exp_avg_sq"].any()
    model = model_of(scene, IN_VIEW[:1], [SMALL], [0.5])
    fit_step(scene, model, default, state, 56)  # a reset step, but past stop
    assert torch.sigmoid(model.params["opacity_logits"].detach()).item() > 0.4


# ---------------------------------------------------------------------------------------------- budget


def opacities_of(model: GaussianModel) -> torch.Tensor:
    return torch.sigmoid(model.params["opacity_logits"].detach())


def test_budget_cuts_an_over_cap_start_to_the_most_opaque(scene):
    opacities = torch.tensor([0.3, 0.9, 0.1, 0.7, 0.5, 0.2, 0.8, 0.4])
    model = model_of(scene, torch.rand(8, 3, generator=torch.Generator().manual_seed(1)) * 0.2, [SMALL] * 8, opacities)
    budget = densifier("budget", cap=3, start=10, every=10)
    budget.step_post_backward(model, budget.initialize_state(scene.scale), 3, None)  # the budget reads no render statistics
    torch.testing.assert_close(opacities_of(model).sort().values, torch.tensor([0.7, 0.8, 0.9]))


def test_budget_relocates_dead_gaussians_onto_live_ones_keeping_their_opacity(scene):
    opacities = [0.6, 0.001, 0.3, 0.002, 0.8, 0.001, 0.4, 0.5]
    model = model_of(scene, torch.rand(8, 3, generator=torch.Generator().manual_seed(1)) * 0.2, [SMALL] * 8, opacities)
    before = {name: tensor.detach().clone() for name, tensor in model.params.items()}
    budget = densifier("budget", cap=100, growth=0.0, dead_opacity=0.005, start=0, every=10)
    budget.step_post_backward(model, budget.initialize_state(scene.scale), 10, None)
    assert model.count == 8 and opacities_of(model).min() >= 0.005
    copies = 0
    for index, opacity in enumerate(opacities):
        rows = rows_of(model, before, index)
        if opacity < 0.005:
            assert len(rows["means"]) == 0  # moved away
            continue
        torch.testing.assert_close(rows["means"], before["means"][index].expand_as(rows["means"]), rtol=0, atol=0)
        shared = torch.sigmoid(rows["opacity_logits"])
        assert (shared == shared[0]).all()
        # Together the source and its k copies are as opaque as the source was: 1 − (1 − o)^(k + 1) = o.
        torch.testing.assert_close(1 - (1 - shared[0]) ** len(shared), torch.tensor(opacity), rtol=1e-4, atol=1e-6)
        copies += len(shared) - 1
    assert copies == 3
    assert_trainable(scene, model)


def test_budget_grows_while_under_the_cap_and_never_beyond_it(scene):
    model = model_of(scene, torch.rand(20, 3, generator=torch.Generator().manual_seed(1)) * 0.2, [SMALL] * 20, [0.5] * 20)
    budget = densifier("budget", cap=30, growth=0.25, start=10, stop=100, every=10)
    state = budget.initialize_state(scene.scale)
    counts = []
    for step in (5, 10, 15, 20, 30, 40, 100):
        budget.step_post_backward(model, state, step, None)
        counts.append(model.count)
    # Off the grid (5, 15) and from stop (100) on nothing grows; 20 → 25 → 30 (+25 %, then the cap).
    assert counts == [20, 25, 25, 30, 30, 30, 30]
    assert_trainable(scene, model)


def test_budget_does_nothing_outside_its_window(scene):
    model = model_of(scene, torch.rand(6, 3, generator=torch.Generator().manual_seed(1)) * 0.2, [SMALL] * 6, [0.5, 0.001] * 3)
    budget = densifier("budget", cap=100, growth=0.5, start=10, stop=30, every=10)
    state = budget.initialize_state(scene.scale)
    for step in (0, 12, 30, 40):
        budget.step_post_backward(model, state, step, None)
        assert model.count == 6 and (opacities_of(model) < 0.005).sum() == 3, step
    budget.step_post_backward(model, state, 20, None)
    assert model.count == 9 and (opacities_of(model) >= 0.005).all()


def test_budget_rejects_a_cap_below_one():
    with pytest.raises(InputError, match="densifier 'budget': cap must be ≥ 1, got 0"):
        densifier("budget", cap=0)


@pytest.mark.parametrize("name, params, message", [
    ("budget", {"cap": 2.5}, "parameter 'cap' must be an integer, got 2.5"),
    ("budget", {"dead_opacity": 1.5}, "dead_opacity must be between 0 and 1, got 1.5"),
    ("budget", {"growth": -0.1}, "growth must be ≥ 0, got -0.1"),
    ("budget", {"every": "often"}, "parameter 'every' must be an integer, got 'often'"),
    ("default", {"grad_threshold": 0.0}, "grad_threshold must be a finite number > 0, got 0.0"),
    ("default", {"prune_opacity": -0.01}, "prune_opacity must be between 0 and 1, got -0.01"),
    ("default", {"reset_every": 0}, "reset_every must be ≥ 1, got 0"),
    ("default", {"start": -1}, "start must be ≥ 0, got -1"),
    ("default", {"split_factor": "half"}, "parameter 'split_factor' must be a number, got 'half'"),
])
def test_densifiers_refuse_out_of_range_and_mistyped_parameters_naming_themselves(name, params, message):
    with pytest.raises(InputError, match=f"densifier '{name}': {message}"):
        densifier(name, **params)
