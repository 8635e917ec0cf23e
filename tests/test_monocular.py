"""Monocular captures: the synthetic orbiting camera in the D-NeRF layout, a first fit over the moving
camera's first images, `deformation` trained over every (frame, camera) image, held-out PSNR from the fixed
cameras, and `iterative` refused before it starts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mmcsplat.cli.main import main
from mmcsplat.configuration.config import load_config
from mmcsplat.pipeline.evaluate import evaluate
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.pipeline.ingest import ingest
from mmcsplat.pipeline.track import track_run
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.session import SessionReader
from mmcsplat.synthetic import SynthConfig
from mmcsplat.synthetic.monocular import synthesize_monocular
from mmcsplat.training.views import MONOCULAR_IMAGES, first_fit_images

FRAMES = 12


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A 12-frame orbit at 64 × 48 with two fixed held-out cameras every 5th frame, ingested."""
    folder = tmp_path_factory.mktemp("monocular")
    written = synthesize_monocular(folder / "capture", SynthConfig(frames=FRAMES, cameras=2, width=64, height=48, samples=1), progress=False)
    assert (written.train_images, written.heldout_images) == (FRAMES, 2 * 3)
    ingest(folder / "capture", folder / "session.zarr", progress=False)
    return folder / "session.zarr"


def test_the_orbit_is_one_camera_per_frame_and_the_fixed_cameras_are_held_out(session):
    reader = SessionReader(session)
    train = [name for name in reader.camera_names if name not in reader.heldout]
    assert len(train) == FRAMES and len(reader.heldout) == 2
    presence = np.stack([reader.present(name) for name in train])
    assert (presence.sum(axis=0) == 1).all() and (presence.sum(axis=1) == 1).all()
    for name in reader.heldout:
        assert np.flatnonzero(reader.present(name)).tolist() == [0, 5, 10]
    centres = np.array([reader.camera(name).center for name in train])
    assert np.allclose(np.linalg.norm(centres[:, :2], axis=1), 1.2)  # on the ring's circle, all around it
    azimuths = np.unwrap(np.arctan2(centres[:, 1], centres[:, 0]))
    assert np.allclose(np.diff(azimuths), 2 * np.pi / FRAMES)
    frame = reader.frame(3, train[3])
    assert frame.mask is not None and 0.005 < frame.mask.mean() < 0.2
    assert not frame.rgb[~frame.mask].any()  # composited over black, as D-NeRF's renders are read


def test_first_fit_images_span_the_moving_cameras_first_poses(session):
    reader = SessionReader(session)
    train = [reader.camera(name) for name in reader.camera_names if name not in reader.heldout]
    images = first_fit_images(reader, train, 0, 0)
    assert images == [(t, t) for t in range(MONOCULAR_IMAGES)]
    assert first_fit_images(reader, train, 2, 3) == [(2, 2), (3, 3), (4, 4)]
    with pytest.raises(InputError, match="hold 1 training image.*fit.window"):
        first_fit_images(reader, train, FRAMES - 1, 0)
    rig = [reader.camera(name) for name in reader.heldout]  # both image frame 0: a rig there
    assert first_fit_images(reader, rig, 0, 0) == [(0, 0), (0, 1)]
    # a rig camera that missed the fitted moment is left out of the first fit, the others train
    assert first_fit_images(reader, [*rig, train[1]], 0, 0) == [(0, 0), (0, 1)]


def test_monocular_capture_fits_tracks_with_deformation_and_is_scored_on_the_fixed_cameras(session, tmp_path):
    config = load_config("paper-masked-sparse", ["fit.iterations=30", "initializer.random.num_points=500"])
    fit = FirstFrameFit(SessionReader(session), config, tmp_path / "run", progress=False)
    assert sorted({t for t, _ in fit.images}) == list(range(MONOCULAR_IMAGES))
    assert [fit.scene.frame_of(i) for i in range(len(fit.scene.cameras))] == list(range(MONOCULAR_IMAGES))
    assert fit.run().complete
    with pytest.raises(InputError, match="iterative.*needs 2 training cameras.*--dynamics deformation"):
        track_run(tmp_path / "run", dynamics="iterative", overrides=["dynamics.iterations=2"], progress=False)
    assert not (tmp_path / "run" / "tracks.zarr").exists()
    track_run(tmp_path / "run", dynamics="deformation", overrides=["dynamics.iterations=40"], progress=False)
    metrics = evaluate(tmp_path / "run")
    scored = [t for t, value in enumerate(metrics["per_frame_val_masked_psnr"]) if value is not None]
    assert scored == [0, 5, 10]
    assert metrics["tracked_val_masked_psnr"] == pytest.approx(np.mean([metrics["per_frame_val_masked_psnr"][t] for t in scored]))
    assert metrics["val_masked_psnr"] is not None  # the fixed cameras image the fitted frame
    assert set(metrics["per_camera"]) == {"train_000", *SessionReader(session).heldout}


def test_synth_monocular_cli(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "capture"), "--monocular", "--num-frames", "3", "--num-cameras", "1",
                 "--width", "32", "--height", "24", "--no-progress"]) == 0
    assert "3 images of one orbiting camera and 1 held-out images" in capsys.readouterr().out
    document = json.loads((tmp_path / "capture" / "transforms_train.json").read_text())
    assert [frame["time"] for frame in document["frames"]] == pytest.approx([0, 1 / 30, 2 / 30])
    assert main(["synth", str(tmp_path / "capture"), "--monocular", "--no-progress"]) == 2  # not over an existing capture
