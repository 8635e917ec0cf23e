"""The ``deformation`` dynamics: the field's encoding and start, the schedules, that it follows a moving
subject, resumes exactly, and that its memory does not grow with the length of the sequence."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from fitting_scene import WIDTH, moved, ring_camera, subject, write_fitted_run, write_session

from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.evaluate import evaluate
from mmcsplat.pipeline.track import track_run
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.plugins.dynamics import deformation
from mmcsplat.plugins.dynamics.deformation import CHECKPOINT, DeformationDynamics, _Run
from mmcsplat.plugins.dynamics.deformation_field import DeformationField, sinusoidal_encoding
from mmcsplat.storage.curves import read_curves
from mmcsplat.storage.session import SessionWriter
from mmcsplat.storage.tracks import TrackReader

FRAMES = 6


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A subject moving over FRAMES frames (sliding 1 cm per frame, one half bending)."""
    return write_session(tmp_path_factory.mktemp("moving") / "session.zarr", frames=FRAMES)


def test_encoding_layout_and_identity_start():
    x = torch.tensor([[0.5, -1.0, 2.0]])
    encoded = sinusoidal_encoding(x, 3)
    assert encoded.shape == (1, 3 * 7)
    torch.testing.assert_close(encoded[0, :3], x[0])
    torch.testing.assert_close(encoded[0, 3 + 3 * 2 : 3 + 3 * 3], torch.sin(4 * x[0]))  # sin, band k = 2
    torch.testing.assert_close(encoded[0, 12 + 3 : 12 + 6], torch.cos(2 * x[0]))  # cos, band k = 1

    field = DeformationField(depth=8, width=32, frequencies=10)
    assert field.layers[4].in_features == 32 + 4 * 21  # the input again at layer 4, as Yang et al.
    means = torch.randn(50, 3, requires_grad=True)
    d_means, d_quats, d_scales = field(means, torch.tensor(0.3))
    assert d_means.shape == (50, 3) and d_quats.shape == (50, 4) and d_scales.shape == (50, 3)
    assert not d_means.any() and not d_quats.any() and not d_scales.any()  # the identity before training
    (d_means.sum() + d_quats.sum()).backward()
    assert means.grad is None  # the field's input is detached
    assert field.head.weight.grad.abs().sum() > 0


def test_time_noise_anneals_by_the_scaled_iteration_and_lr_decays():
    study = DeformationDynamics(iterations=40_000)
    assert study.noise_std(0, frames=11) == pytest.approx(0.1 / 10)  # 0.1 frame intervals
    assert study.noise_std(10_000, frames=11) == pytest.approx(0.05 / 10)
    assert study.noise_std(20_000, frames=11) == 0.0
    short = DeformationDynamics(iterations=4000)  # annealed over 2000: half the run, as the study
    assert short.noise_std(1000, frames=11) == pytest.approx(0.05 / 10)
    assert short.noise_std(2000, frames=11) == 0.0
    assert short.mlp_lr(0) == pytest.approx(short.lr) and short.mlp_lr(4000) == pytest.approx(short.lr_final)
    assert short.densifier_params()["stop"] == 2000
    assert DeformationDynamics(densifier={"name": "budget", "cap": 10}).densifier_params() == {"name": "budget", "cap": 10}
    with pytest.raises(InputError, match="dynamics 'deformation': unknown parameter.*iteratons"):
        default_registry().create("dynamics", "deformation", iteratons=10)
    with pytest.raises(InputError, match="dynamics 'deformation': checkpoint_every must be ≥ 1"):
        default_registry().create("dynamics", "deformation", checkpoint_every=0)


def test_follows_a_moving_subject(session, tmp_path):
    run = write_fitted_run(tmp_path / "run", session)  # the true subject at frame 0
    record = track_run(run, dynamics="deformation", overrides=["dynamics.iterations=300"], progress=False)
    tracks = TrackReader(run)
    assert tracks.method == "deformation" and tracks.num_frames == FRAMES
    assert set(tracks.dynamic) == {"means", "quats", "log_scales"}
    assert record["summary"]["iterations"] == 300 and (run / CHECKPOINT).exists()
    # The subject slides 1 cm per frame along x: the Gaussians' mean displacement follows it.
    truth = np.stack([moved(subject(), t).means.numpy() for t in range(FRAMES)])
    shift = (tracks.means(FRAMES - 1) - tracks.means(0)).mean(axis=0)
    true_shift = (truth[-1] - truth[0]).mean(axis=0)
    assert abs(shift[0] - true_shift[0]) < 0.3 * abs(true_shift[0])
    # The tracked model's size is reported beside the first-frame fit's (densification may change it).
    metrics = evaluate(run)
    assert metrics["tracking_num_gaussians"] == tracks.num_gaussians and metrics["num_gaussians"] == subject().count


def test_killed_run_resumes_to_the_same_tracks(session, tmp_path, monkeypatch):
    settings = ["dynamics.iterations=40", "dynamics.checkpoint_every=10", "dynamics.densifier.start=5", "dynamics.densifier.every=10"]
    monkeypatch.setattr(deformation, "CURVE_EVERY", 10)
    straight = write_fitted_run(tmp_path / "straight", session)
    track_run(straight, dynamics="deformation", overrides=settings, progress=False)

    original = _Run._checkpoint

    def killed_after_20(self, path):
        original(self, path)
        if self.step == 20:
            raise KeyboardInterrupt  # as a kill between checkpoints
    monkeypatch.setattr(_Run, "_checkpoint", killed_after_20)
    resumed = write_fitted_run(tmp_path / "resumed", session)
    with pytest.raises(KeyboardInterrupt):
        track_run(resumed, dynamics="deformation", overrides=settings, progress=False)
    assert not (resumed / "tracks.zarr").exists()
    monkeypatch.setattr(_Run, "_checkpoint", original)
    record = track_run(resumed, dynamics="deformation", overrides=settings, progress=False)
    assert record["summary"]["resumed_from"] == 20  # and says so
    a, b = TrackReader(straight), TrackReader(resumed)
    assert a.num_gaussians == b.num_gaussians
    for k in (0, FRAMES - 1):
        np.testing.assert_array_equal(a.means(k), b.means(k))
    # RUN/curves.csv: the resumed run's rows are the straight run's, none lost or repeated by the kill.
    straight_rows, resumed_rows = ([row for row in read_curves(run) if row["stage"] == "track"] for run in (straight, resumed))
    assert [row["step"] for row in straight_rows] == [10, 20, 30, 40]
    assert [(r["step"], r["loss"], r["psnr"]) for r in resumed_rows] == [(r["step"], r["loss"], r["psnr"]) for r in straight_rows]

    shutil.rmtree(resumed / "tracks.zarr")  # a kept checkpoint of other settings is refused, not resumed
    with pytest.raises(ValueError, match="deformation.pt: its settings differ from this run.s"):
        track_run(resumed, dynamics="deformation", overrides=["dynamics.iterations=50"], progress=False)


# ------------------------------------------------------------------------------------------- streaming

STREAM_WIDTH, STREAM_HEIGHT, STREAM_CAMERAS = 640, 480, 4
LONG = 560  # frames of the long session
PEAK_RSS = """
import resource, sys
from mmcsplat.pipeline.track import track_run
track_run(sys.argv[1], dynamics="deformation", progress=False,
          overrides=["dynamics.iterations=60", "dynamics.cache_bytes=4000000", "dynamics.densifier.stop=0"])
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
"""


def write_long_session(path: Path, frames: int) -> Path:
    """``frames`` frames of the subject in STREAM_CAMERAS 640×480 views, each camera's first image rolled
    sideways a pixel per frame (cheap to make, and frames differ)."""
    renderer = default_registry().create("renderer", "torch-cpu")
    rig = [ring_camera(f"cam_{i}", 2 * np.pi * i / STREAM_CAMERAS).scaled(STREAM_WIDTH / WIDTH) for i in range(STREAM_CAMERAS)]
    truth = subject()
    gaussians = Gaussians(*(getattr(truth, name).float() for name in ("means", "quats", "log_scales", "opacity_logits", "colors", "features")))
    with SessionWriter(path, cameras=rig, num_frames=frames, fps=30.0, heldout=("cam_0",), source="streaming-test") as writer:
        for camera in rig:
            with torch.no_grad():
                out = renderer.render(gaussians, RenderCameras.from_cameras([camera]))
            rgb = (out.rgb[0].clamp(0, 1).numpy() * 255).round().astype(np.uint8)
            mask = out.alpha[0].numpy() > 0.5
            for t in range(frames):
                writer.write_frame(camera.name, t, np.roll(rgb, t % 40, axis=1), mask=np.roll(mask, t % 40, axis=1))
    return path


def peak_rss(*runs: Path) -> list[int]:
    """Peak resident memory (bytes) of tracking each of ``runs``, each in a fresh interpreter (together)."""
    processes = [subprocess.Popen([sys.executable, "-c", PEAK_RSS, str(run)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for run in runs]
    peaks = []
    for process in processes:
        out, err = process.communicate(timeout=300)
        assert process.returncode == 0, err[-3000:]
        peaks.append(int(out.split()[-1]))
    return peaks


@pytest.mark.slow
def test_memory_does_not_grow_with_the_sequence(tmp_path):
    """Peak RSS on LONG frames within 1.25× that on 25 (same settings, a 4 MB frame cache), as issue #5 asks.

    The LONG-frame session decodes to 2 GB, larger than the whole process (0.7–1.4 GB, depending on the
    machine's threads and state: 1.43 GB was seen once inside a full CI run), so a run that held the
    sequence could not pass."""
    runs = {frames: write_fitted_run(tmp_path / f"run{frames}", write_long_session(tmp_path / f"s{frames}.zarr", frames)) for frames in (25, LONG)}
    short, long = peak_rss(runs[25], runs[LONG])
    decoded = LONG * (STREAM_CAMERAS - 1) * STREAM_WIDTH * STREAM_HEIGHT * 4  # rgb + mask of every training image
    print(f"peak RSS: {short / 2**20:.0f} MiB on 25 frames, {long / 2**20:.0f} MiB on {LONG} ({long / short:.2f}×); the {LONG} frames decode to {decoded / 2**20:.0f} MiB")
    assert decoded > short, "the sequence must be large enough that holding it would break the bound"
    assert long <= 1.25 * short, f"peak RSS {long / 2**20:.0f} MiB on 400 frames vs {short / 2**20:.0f} MiB on 25"
    summary = json.loads((runs[LONG] / "track.json").read_text())["summary"]
    assert summary["cache_bytes"] == 4_000_000 and summary["cache_misses"] > 45  # images were drawn across the sequence
