"""Coarse to fine: a frame's first steps on its views at reduced resolution, the last at full size."""

from __future__ import annotations

import numpy as np
import torch
from rig_fixtures import ring_cameras

from mmcsplat.backends.torch_reference import TorchReferenceRenderer
from mmcsplat.plugin_api.interfaces import TrainingView
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.training.coarse_views import CoarseToFine, coarse_camera, coarse_view

CAMERAS = ring_cameras(["a", "b"], width=97, height=73, distortion=(0, 0, 0, 0, 0))  # odd sizes: a remainder is cropped


def view(index: int) -> TrainingView:
    image = torch.rand(73, 97, 3, generator=torch.Generator().manual_seed(index))
    mask = torch.zeros(73, 97, dtype=torch.bool)
    mask[20:41, 30:61] = True
    return TrainingView(CAMERAS[index], index, image, mask, mask[..., None].float(), torch.tensor([0.1, 0.2, 0.3]))


def test_a_coarse_pixel_sees_what_its_block_of_fine_pixels_sees():
    camera = CAMERAS[0]
    coarse = coarse_camera(camera, 2)
    assert (coarse.width, coarse.height) == (48, 36)
    points = np.array([[0.1, -0.2, 0.05], [-0.3, 0.1, 0.2]])
    fine, reduced = camera.project(points), coarse.project(points)
    np.testing.assert_allclose(reduced, (fine - 0.5) / 2, atol=1e-9)  # fine pixels 0 and 1 make coarse pixel 0, centred at 0.5


def test_coarse_view_averages_blocks():
    reduced = coarse_view(view(0), 2)
    assert reduced.image.shape == (36, 48, 3) and reduced.mask.shape == (36, 48) and reduced.seg_target.shape == (36, 48, 1)
    torch.testing.assert_close(reduced.image[3, 5], view(0).image[6:8, 10:12].mean(dim=(0, 1)))
    assert reduced.mask[10:20, 15:30].all() and not reduced.mask[:10].any()  # rows 20–40 of 73 → 10–19 (a half-covered block counts)
    assert reduced.seg_target[10, 15, 0] == 1.0 and reduced.seg_target[20, 15, 0] == 0.5  # row 40 is inside, row 41 not


def test_coarse_steps_render_at_reduced_size_and_the_last_at_full_size():
    cameras = RenderCameras.each(CAMERAS)
    stages = CoarseToFine([view(0), view(1)], cameras, factor=2, coarse_steps=3)
    gaussians = Gaussians.from_linear(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.05), torch.tensor([0.9]),
                                      torch.full((1, 3), 0.5), torch.zeros(1, 1))
    sizes = []
    for step in range(5):
        step_view, step_cameras = stages.at(step, step % 2)
        render = TorchReferenceRenderer().render(gaussians, step_cameras)
        assert render.rgb.shape[1:3] == step_view.image.shape[:2] and step_view.index == step % 2
        sizes.append(tuple(render.rgb.shape[1:3]))
    assert sizes == [(36, 48)] * 3 + [(73, 97)] * 2
    assert stages.at(0, 0)[0] is stages.at(2, 0)[0]  # reduced once per frame
