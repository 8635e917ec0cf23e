"""Supersampled rendering (``fit.supersample``): sub-pixels in the right place, depth kept the expected
depth, and a run fitted at N× evaluated at N× — a capture whose pixels integrate over their area is
matched by its true scene only when the render does the same."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from fitting_scene import every_renderer, ring_camera, subject, write_config, write_fitted_run, write_session

from mmcsplat.backends.torch_reference import TorchReferenceRenderer
from mmcsplat.configuration.config import load_config
from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.evaluate import evaluate
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.pipeline.track import track_run
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.settings import FitSettings
from mmcsplat.training.supersampling import SupersampledRenderer, subpixel_cameras, supersampled

TRUTH = subject(count=60, scale=0.01)


def _alpha_centroid(alpha: torch.Tensor) -> np.ndarray:
    v, u = np.mgrid[: alpha.shape[0], : alpha.shape[1]]
    weights = alpha.numpy()
    return np.array([(u * weights).sum(), (v * weights).sum()]) / weights.sum()


def _one_gaussian(point: list[float], scale: float, dtype: torch.dtype = torch.float64) -> Gaussians:
    """One white, half-transparent (no pixel clamped at full opacity) isotropic Gaussian."""
    return Gaussians.from_linear(torch.tensor([point], dtype=dtype), torch.tensor([[1.0, 0, 0, 0]], dtype=dtype),
                                 torch.full((1, 3), scale, dtype=dtype), torch.tensor([0.5], dtype=dtype), torch.ones(1, 3, dtype=dtype))


def test_subpixels_are_centred_in_their_pixel():
    camera = ring_camera("cam_0", 0.3)
    point = np.array([[0.05, -0.02, 0.03]])
    u, v = camera.project(point)[0]
    fine = subpixel_cameras(RenderCameras.from_cameras([camera], dtype=torch.float64), 3)
    local = point @ camera.R.T + camera.t
    projected = (fine.K[0].numpy() @ local[0])[:2] / local[0, 2]
    np.testing.assert_allclose(projected, [3 * u + 1, 3 * v + 1], atol=1e-9)  # the middle of its 3 × 3 block
    assert (fine.width, fine.height) == (3 * camera.width, 3 * camera.height)


@pytest.mark.parametrize("factor", [2, 3])
def test_a_supersampled_render_stays_where_the_plain_one_is(factor):
    """A Gaussian's image lands on the same spot (a sub-pixel grid off by its offset would move it by a
    quarter pixel at 2×), and the depth is still its distance wherever it is drawn."""
    camera = ring_camera("cam_0", 0.3)
    cameras = RenderCameras.from_cameras([camera], dtype=torch.float64)
    gaussians = _one_gaussian([0.03, 0.02, 0.01], 0.05)  # σ ≈ 1.4 px
    plain = TorchReferenceRenderer().render(gaussians, cameras)
    fine = SupersampledRenderer(TorchReferenceRenderer(), factor).render(gaussians, cameras)
    assert fine.rgb.shape == plain.rgb.shape and fine.alpha.shape == plain.alpha.shape
    np.testing.assert_allclose(_alpha_centroid(fine.alpha[0]), _alpha_centroid(plain.alpha[0]), atol=0.01)
    z = float((gaussians.means.numpy() @ camera.R.T + camera.t)[0, 2])
    drawn = fine.alpha[0] > 0
    np.testing.assert_allclose(fine.depth[0][drawn].numpy(), z, rtol=1e-9)
    assert float(fine.depth[0][~drawn].abs().max()) == 0.0


@pytest.mark.parametrize("backend", every_renderer())
def test_every_backend_supersamples(backend):
    """The wrapper only moves cameras and averages blocks, so each backend keeps its own render's place."""
    renderer = default_registry().create("renderer", backend)
    cameras = RenderCameras.from_cameras([ring_camera("cam_0", 0.3)])
    gaussians = _one_gaussian([0.03, 0.02, 0.01], 0.05, torch.float32)
    plain, fine = renderer.render(gaussians, cameras), SupersampledRenderer(renderer, 2).render(gaussians, cameras)
    np.testing.assert_allclose(_alpha_centroid(fine.alpha[0].detach().cpu()), _alpha_centroid(plain.alpha[0].detach().cpu()), atol=0.01)


def test_factor_one_is_the_renderer_itself_and_bad_factors_are_refused():
    renderer = TorchReferenceRenderer()
    assert supersampled(renderer, 1) is renderer
    for bad, message in ((0, "supersample must be ≥ 1, got 0"), (1.5, "'supersample' must be an integer, got 1.5"),
                         (True, "'supersample' must be an integer, got True")):
        with pytest.raises(ValueError, match=message):
            FitSettings.from_table({"supersample": bad}, "test")


@pytest.fixture(scope="module")
def integrating(tmp_path_factory) -> SessionReader:
    """The fitting scene at 2× its base resolution, seen by cameras whose pixels average 3 × 3 sub-pixels."""
    return SessionReader(write_session(tmp_path_factory.mktemp("integrating") / "scene.zarr", frames=2, zoom=2, truth=TRUTH, supersample=3))


def test_evaluation_and_tracking_render_a_run_as_it_was_fitted(integrating, tmp_path):
    """The true scene scores near-perfectly only when the evaluation averages sub-pixels as the capture did;
    tracking it into the next frame renders the same way."""
    scores = {factor: evaluate(write_fitted_run(tmp_path / f"x{factor}", integrating.url, TRUTH, supersample=factor))["val_psnr"]
              for factor in (1, 3)}
    assert scores[3] > 45 and scores[3] > scores[1] + 8
    tracked = {}
    for factor in (1, 3):
        track_run(tmp_path / f"x{factor}", dynamics="iterative", overrides=["dynamics.iterations=20"], progress=False)
        tracked[factor] = evaluate(tmp_path / f"x{factor}")["per_frame_val_masked_psnr"]
    assert tracked[3][1] > tracked[1][1] + 5  # measured: 26.1 against 19.1 dB


def test_a_supersampled_fit_learns_and_records_its_factor(integrating, tmp_path):
    config = load_config(write_config(tmp_path / "fit.toml", iterations=60), ["fit.supersample=2"])
    info = FirstFrameFit(integrating, config, tmp_path / "run", progress=False).run()
    assert info.supersample == 2
    assert evaluate(tmp_path / "run")["train_masked_psnr"] > 12  # an empty render scores about 8 dB inside these masks
