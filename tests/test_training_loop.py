"""The training driver (mmcsplat.training.loop) on the tiny fitting scene (tests/fitting_scene.py): extra
loss terms are added to the per-view objective, pruning rules remove Gaussians, checkpoints come every N
steps and after the last, a non-finite step names where it happened, and the stopping rule ends a
training whose loss has stopped improving before its cap (and is off unless asked for), and every step
keeps the CPU thread count to the free cores."""

from __future__ import annotations

import pytest
import torch
from fitting_scene import scene_context, subject, write_session

from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.render_contract import RenderCameras
from mmcsplat.storage.session import SessionReader
from mmcsplat.training import threads
from mmcsplat.training.finite import FitError, NonFiniteError
from mmcsplat.training.loop import PlateauStop, Sample, TrainingLoop
from mmcsplat.training.model import GaussianModel, LearningRates
from mmcsplat.training.objective import view_loss
from mmcsplat.training.settings import FitSettings
from mmcsplat.training.views import load_view


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return scene_context(SessionReader(write_session(tmp_path_factory.mktemp("scene") / "scene.zarr")))


def new_model(scene) -> GaussianModel:
    return GaussianModel(subject(count=40), tuple(camera.name for camera in scene.cameras), LearningRates(), scene.scale)


@pytest.fixture
def model(scene) -> GaussianModel:
    return new_model(scene)


def loop_of(model: GaussianModel, **options) -> TrainingLoop:
    return TrainingLoop(model, default_registry().create("renderer", "torch-reference"), FitSettings(), **options)


def sampler(scene, model: GaussianModel):
    """Each step on the next training camera in turn, rendering the model's own Gaussians."""
    views = [load_view(scene.session, scene.frame, camera, index, (), torch.zeros(3)) for index, camera in enumerate(scene.cameras)]
    cameras = RenderCameras.each(scene.cameras)
    return lambda step: Sample(views[step % len(views)], cameras[step % len(views)], model.gaussians())


def test_extra_terms_are_added_to_the_objective_seeing_the_step_and_its_view(scene, model):
    seen = []

    def term(step, render, view):
        seen.append((step, view.index))
        return None if step % 2 else render.alpha.sum() * 0 + 0.5

    loop = loop_of(model, terms=[term])
    sample = sampler(scene, model)

    def objective(number: int) -> float:  # the per-view objective of a step's sample, from the model as it is now
        drawn = sample(number)
        return view_loss(model, drawn.view, loop.renderer.render(drawn.gaussians, drawn.cameras), FitSettings())[0].item()

    before = objective(0)
    assert float(loop.train_step(0, sample(0)).loss) == pytest.approx(before + 0.5, rel=1e-6)
    before = objective(1)
    assert float(loop.train_step(1, sample(1)).loss) == pytest.approx(before, rel=1e-6)  # the term said None: nothing added
    assert seen == [(0, 0), (1, 1)] and loop.step == 1


def test_pruning_rules_remove_their_union_and_pruning_everything_is_an_error(scene, model):
    loop = loop_of(model, prune=[lambda step, m: torch.arange(m.count) < 3, lambda step, m: None if step else torch.arange(m.count) == 39])
    sample = sampler(scene, model)
    assert loop.train_step(0, sample(0)).gaussians == 36
    assert model.count == 36 and all(tensor.shape[0] == 36 for tensor in model.params.values())
    loop.prune.append(lambda step, m: torch.ones(m.count, dtype=torch.bool))
    with pytest.raises(FitError, match="every Gaussian was pruned at iteration 1"):
        loop.train_step(1, sample(1))


def test_run_records_every_step_and_checkpoints_every_n_and_after_the_last(scene, model):
    recorded, saved = [], []
    loop = loop_of(model)
    done = loop.run(range(2, 9), sampler(scene, model), record=lambda step: recorded.append(step.number), checkpoint=saved.append,
                    checkpoint_every=3, progress=False)
    assert done == 9 and recorded == list(range(2, 9)) and saved == [3, 6, 9]


def test_a_non_finite_step_names_where_it_happened(scene):
    def nan_at_1(step, render, view):
        return torch.tensor(float("nan")) if step == 1 else None

    for where, prefix in (("frame 7", "frame 7: "), (None, "")):
        model = new_model(scene)
        with pytest.raises(NonFiniteError, match=rf"^{prefix}the loss became nan at iteration 1$"):
            loop_of(model, terms=[nan_at_1]).run(range(3), sampler(scene, model), where=where, progress=False)


def test_plateau_stop_waits_for_patience_blocks_without_improvement():
    rule = PlateauStop(window=2, patience=2, tolerance=0.1)
    # Block means 1.0 (first), 0.5 (improves), 0.47 (within 10 %: stale), 0.2 (improves), 0.19, 0.19: stop.
    losses = [1.0, 1.0, 0.6, 0.4, 0.47, 0.47, 0.2, 0.2, 0.19, 0.19, 0.19, 0.19]
    stops = [rule.update(loss) for loss in losses]
    assert stops == [False] * 11 + [True]
    rule.reset()
    assert not any(rule.update(loss) for loss in [1.0, 1.0, 0.5, 0.5, 0.25, 0.25, 0.1, 0.1])  # halving every block: never


def test_the_stopping_rule_ends_a_flat_training_before_its_cap_and_is_off_by_default(scene, model):
    for optimizer in model.optimizers.values():  # nothing learns: the loss repeats each pass over the cameras
        optimizer.param_groups[0]["lr"] = 0.0
    loop, sample, cameras = loop_of(model), sampler(scene, model), len(scene.cameras)
    saved = []
    done = loop.run(range(100), sample, stop=PlateauStop(window=cameras, patience=2), checkpoint=saved.append, progress=False)
    assert done == 3 * cameras and saved == [done]  # the first block sets the mark, two more without a better one stop
    assert loop.run(range(2 * cameras), sample, progress=False) == 2 * cameras


def test_every_step_keeps_the_thread_count_to_the_free_cores(scene, model, monkeypatch):
    """The loop asks the process's thread policy before each step (mmcsplat.training.threads)."""
    asked = []

    class Policy:
        def update(self):
            asked.append(len(asked))
            return 1

    monkeypatch.setattr(threads, "_policy", Policy())
    loop_of(model).run(range(0, 4), sampler(scene, model), progress=False)
    assert asked == [0, 1, 2, 3]


def test_gaussians_without_a_segmentation_colour_start_undecided():
    """An initializer's Gaussians without feature columns (a third party's grid) start at segmentation colour
    0.5, as the built-in initializers start theirs; they started at 0, as background."""
    from mmcsplat.plugin_api.render_contract import Gaussians

    bare = subject(count=5)
    bare = Gaussians(bare.means, bare.quats, bare.log_scales, bare.opacity_logits, bare.colors, bare.means.new_zeros((5, 0)))
    model = GaussianModel(bare, ("a",), LearningRates(), 1.0)
    assert torch.allclose(torch.sigmoid(model.params["seg_logits"]), torch.full((5, 1), 0.5, dtype=model.params["seg_logits"].dtype))
