"""The windowed photometric loss of tracking (colour correction frozen): computed over the window the
Gaussians reach plus the backdrop's share from a per-view table, it equals the whole image's loss in value
and gradients — for a window inside the image and one cut by the image's border."""

from __future__ import annotations

import pytest
import torch
from fitting_scene import scene_context, subject, write_session

from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.render_contract import RenderCameras
from mmcsplat.storage.session import SessionReader
from mmcsplat.training import losses
from mmcsplat.training.model import GaussianModel, LearningRates
from mmcsplat.training.objective import changed_window, view_loss
from mmcsplat.training.settings import FitSettings
from mmcsplat.training.views import load_view


@pytest.mark.parametrize("box", [(slice(9, 21), slice(14, 30)), (slice(0, 12), slice(25, 40))], ids=["inside", "on-the-border"])
def test_windowed_loss_equals_the_whole_images(box):
    g = torch.Generator().manual_seed(0)
    static = torch.rand(30, 40, 3, generator=g, dtype=torch.float64)
    target = torch.rand(30, 40, 3, generator=g, dtype=torch.float64)
    inside = (torch.rand(static[box].shape, generator=g, dtype=torch.float64) - 0.5).requires_grad_(True)

    def image() -> torch.Tensor:  # the static image, changed inside the box alone
        change = torch.zeros(30, 40, 3, dtype=torch.float64)
        change[box] = inside
        return static + change

    whole = losses.photometric_loss(image(), target)
    (expected,) = torch.autograd.grad(whole, inside)
    rows, columns = box
    reach = losses.SSIM_REACH
    window = (slice(max(rows.start - reach, 0), min(rows.stop + reach, 30)), slice(max(columns.start - reach, 0), min(columns.stop + reach, 40)))
    windowed = losses.windowed_photometric_loss(image(), target, losses.StaticPhotometric.of(static, target), *window)
    (got,) = torch.autograd.grad(windowed, inside)
    assert windowed.item() == pytest.approx(whole.item(), rel=1e-12)
    torch.testing.assert_close(got, expected, rtol=1e-9, atol=1e-14)


def test_tracking_view_loss_uses_the_window_and_matches_the_fits(tmp_path):
    scene = scene_context(SessionReader(write_session(tmp_path / "scene.zarr")))
    renderer = default_registry().create("renderer", "torch-reference")
    settings = FitSettings(lambda_seg=0.5)
    model = GaussianModel(subject(count=40), tuple(camera.name for camera in scene.cameras), LearningRates(), scene.scale)
    backdrop = torch.rand(scene.cameras[0].height, scene.cameras[0].width, 3, generator=torch.Generator().manual_seed(1))
    view = load_view(scene.session, scene.frame, scene.cameras[0], 0, (), backdrop)
    camera = RenderCameras.each(scene.cameras)[0]
    means = model.params["means"]
    with torch.no_grad():  # shrink the subject so that it covers a corner of the image
        means.mul_(0.3)

    def loss_and_gradient():
        render = renderer.render(model.gaussians(), camera)
        loss, _ = view_loss(model, view, render, settings)
        return render, float(loss.detach()), torch.autograd.grad(loss, [means, model.params["color_logits"]])

    whole_render, whole, whole_grads = loss_and_gradient()
    model.camera_scale.requires_grad_(False)
    model.camera_offset.requires_grad_(False)
    render, windowed, grads = loss_and_gradient()
    assert changed_window(render.alpha[0]) is not None  # the window was used
    assert windowed == pytest.approx(whole, rel=1e-5)
    for got, expected in zip(grads, whole_grads, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-8)
