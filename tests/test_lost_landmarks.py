"""Lost landmarks: a subject whose limb kicks at frame KICK, tracked twice — truly, and with the limb's
Gaussians frozen where they were — is judged against its masks: the true tracks lose no landmark, the
frozen ones lose the limb's landmark alone, from the kick on; landmarks.json records it, `landmarks` and
`evaluate` print it, metrics.json and the report show it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from fitting_scene import ring_camera, write_fitted_run
from scipy.spatial.transform import Rotation

from mmcsplat.analysis.lost_landmarks import LostRule, lost_frames, lost_line, lost_record
from mmcsplat.cli import main
from mmcsplat.outputs.report_landmarks import landmarks_section
from mmcsplat.plugin_api.render_contract import Gaussians
from mmcsplat.storage.landmark_formats import write_landmark_csv
from mmcsplat.storage.session import SessionWriter
from mmcsplat.storage.tracks import TrackWriter

FRAMES, KICK = 7, 3
SIGMA = 0.02  # metres: each Gaussian's scale
HIP = np.array([0.06, 0.0, 0.0])  # the limb turns about the y axis through it
NAMES = ("RAnkle", "LHip", "Neck")
START = np.array([[0.24, 0.0, 0.0], [0.0, -0.03, 0.0], [-0.03, 0.02, 0.01]])  # RAnkle at the limb's end, the others on the trunk


def body() -> tuple[Gaussians, np.ndarray]:
    """(a trunk of 100 Gaussians about the origin and a limb of 24 along x from 10 to 26 cm, which of them are the limb)."""
    g = torch.Generator().manual_seed(1)
    trunk = torch.randn(100, 3, generator=g, dtype=torch.float64) * torch.tensor([0.04, 0.06, 0.04], dtype=torch.float64)
    along = torch.linspace(0.10, 0.26, 12, dtype=torch.float64)
    limb = torch.cat([torch.stack([along, torch.full_like(along, side), torch.zeros_like(along)], dim=1) for side in (-0.01, 0.01)])
    means = torch.cat([trunk, limb])
    count = len(means)
    gaussians = Gaussians(means, torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(count, 1),
                          torch.full((count, 3), float(np.log(SIGMA)), dtype=torch.float64), torch.full((count,), 3.0, dtype=torch.float64),
                          torch.rand(count, 3, generator=g, dtype=torch.float64), torch.ones(count, 1, dtype=torch.float64))
    return gaussians, np.arange(count) >= len(trunk)


def kick(t: int) -> Rotation:
    """The limb's turn at frame t: none before KICK, then 1 rad and 0.1 rad more each frame."""
    return Rotation.from_euler("y", 0.0 if t < KICK else 1.0 + 0.1 * (t - KICK))


def posed(means: np.ndarray, quats: np.ndarray, moving: np.ndarray, turn: Rotation) -> tuple[np.ndarray, np.ndarray]:
    """``means`` and (w, x, y, z) ``quats`` with the ``moving`` ones turned by ``turn`` about HIP."""
    means, quats = means.copy(), quats.copy()
    means[moving] = turn.apply(means[moving] - HIP) + HIP
    quats[moving] = (turn * Rotation.from_quat(quats[moving], scalar_first=True)).as_quat(scalar_first=True)
    return means, quats


def silhouette(camera, means: np.ndarray, sigma: float) -> np.ndarray:
    """[H, W] bool: the discs of 2 ``sigma`` about the Gaussians' centres ``means`` [N, 3] as ``camera`` sees them."""
    import cv2

    mask = np.zeros((camera.height, camera.width), dtype=np.uint8)
    depths = (means @ camera.R.T + camera.t)[:, 2]
    for (u, v), depth in zip(np.round(camera.project(means)).astype(int), depths, strict=True):
        cv2.circle(mask, (int(u), int(v)), round(camera.K[0, 0] * 2 * sigma / depth), 1, thickness=-1)
    return mask.astype(bool)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """(the session — masks the body's silhouettes —, the landmarks file, the body and which of its Gaussians are the limb)."""
    root = tmp_path_factory.mktemp("lost")
    gaussians, limb = body()
    rig = [ring_camera(f"cam_{i}", 2 * np.pi * i / 5 + 0.3, zoom=2) for i in range(5)]
    with SessionWriter(root / "session.zarr", cameras=rig, num_frames=FRAMES, fps=30.0, heldout=("cam_0",), source="kick") as writer:
        for t in range(FRAMES):
            means = posed(gaussians.means.numpy(), gaussians.quats.numpy(), limb, kick(t))[0]
            for camera in rig:
                mask = silhouette(camera, means, SIGMA)
                writer.write_frame(camera.name, t, np.repeat(mask[..., None] * np.uint8(200), 3, axis=2), mask=mask)
    landmarks = root / "joints.csv"
    truth = np.stack([posed(START, np.tile([1.0, 0, 0, 0], (len(START), 1)), np.array([True, False, False]), kick(t))[0] for t in range(FRAMES)])
    write_landmark_csv(landmarks, NAMES, np.arange(FRAMES), np.arange(FRAMES) / 30.0, truth)
    return root / "session.zarr", landmarks, gaussians, limb


def tracked(capture, run, frozen: bool):
    """A run of ``capture`` whose tracks move the limb as it kicked, or leave it (``frozen``) where it was."""
    from mmcsplat.training.fitted_run import FittedRun

    session, _, gaussians, limb = capture
    write_fitted_run(run, session, truth=gaussians)
    params = FittedRun.load(run).params
    means, quats = params["means"].double().numpy(), params["quats"].double().numpy()
    with TrackWriter(run, num_frames=FRAMES, static={k: params[k] for k in ("log_scales", "opacity_logits", "color_logits", "seg_logits")},
                     method="test", attrs={"first_frame": 0}) as writer:
        for t in range(FRAMES):
            moved_means, moved_quats = posed(means, quats, limb, kick(0 if frozen else t))
            writer.write_frame(t, means=torch.as_tensor(moved_means, dtype=torch.float32), quats=torch.as_tensor(moved_quats, dtype=torch.float32))
    return run


def test_true_tracks_lose_no_landmark(capture, tmp_path, capsys):
    run = tracked(capture, tmp_path / "run", frozen=False)
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={capture[1]}"]) == 0
    assert "no landmark lost: every carried landmark followed the subject masks (7 frames judged) — masks only" in capsys.readouterr().out
    lost = json.loads((run / "landmarks.json").read_text())["lost"]
    assert lost["frames_judged"] == FRAMES and set(lost["tolerance_px"]) == {"cam_1", "cam_2", "cam_3", "cam_4"}
    assert lost["landmarks"] == {name: {"first_lost_frame": None, "lost_frames": [], "found_by": []} for name in NAMES} and not lost["flow_judged"]


def test_a_frozen_limb_loses_its_landmark_from_the_kick(capture, tmp_path, capsys):
    run = tracked(capture, tmp_path / "run", frozen=True)
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={capture[1]}"]) == 0
    assert f"lost (off the subject masks or slipped from the optical flow in most cameras): RAnkle from frame {KICK} ({FRAMES - KICK} frames; masks)" in capsys.readouterr().out
    lost = json.loads((run / "landmarks.json").read_text())["lost"]["landmarks"]
    assert lost["RAnkle"] == {"first_lost_frame": KICK, "lost_frames": list(range(KICK, FRAMES)), "found_by": ["masks"]}
    assert lost["LHip"]["first_lost_frame"] is None and lost["Neck"]["first_lost_frame"] is None
    assert main(["evaluate", str(run)]) == 0
    assert f"lost_landmarks         lost (off the subject masks or slipped from the optical flow in most cameras): RAnkle from frame {KICK}" in capsys.readouterr().out
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["lost_landmarks"]["landmarks"]["RAnkle"]["first_lost_frame"] == KICK
    page = landmarks_section(run, [])
    assert "<h3>Lost landmarks</h3>" in page and '<td>RAnkle</td><td class="number">3</td><td class="number">4</td><td>masks</td>' in page


def test_a_short_excursion_is_not_lost():
    off = np.zeros((8, 2), dtype=bool)
    off[1:3, 0] = True  # two frames: a mask's noise
    off[4:7, 1] = True  # three: lost
    np.testing.assert_array_equal(lost_frames(off, 3).nonzero(), ([4, 5, 6], [1, 1, 1]))
    record = lost_record(("a", "b", "c"), np.array([True, True, False]), np.arange(10, 18), np.c_[off, off[:, 1]], np.ones(8, bool), LostRule(), {})
    assert record["landmarks"] == {"a": {"first_lost_frame": None, "lost_frames": [], "found_by": []},
                                   "b": {"first_lost_frame": 14, "lost_frames": [14, 15, 16], "found_by": ["masks"]}}
    assert lost_line(record).startswith("lost (off the subject masks or slipped from the optical flow in most cameras): b from frame 14 (3 frames; masks)")
    assert lost_line(lost_record(("a",), np.array([True]), np.arange(8), off[:, :1], np.zeros(8, bool), LostRule(), {})).startswith("lost landmarks not judged")


def test_landmarks_carried_out_of_every_image_are_lost(capture, tmp_path, capsys):
    """Tracks that fly off: the landmarks' neighbourhoods project beyond every camera's image edge from the kick
    on. Such a point is at least as far from the mask as from the edge; before, it was not judged at all and
    the run said "no landmark lost" with the joints metres away."""
    from mmcsplat.training.fitted_run import FittedRun

    session, landmarks, gaussians, limb = capture
    run = tmp_path / "run"
    write_fitted_run(run, session, truth=gaussians)
    params = FittedRun.load(run).params
    with TrackWriter(run, num_frames=FRAMES, static={k: params[k] for k in ("log_scales", "opacity_logits", "color_logits", "seg_logits")},
                     method="test", attrs={"first_frame": 0}) as writer:
        for t in range(FRAMES):
            means, quats = posed(params["means"].double().numpy(), params["quats"].double().numpy(), limb, kick(t))
            flown = means + (np.array([0.0, 0.0, -3.0]) if t >= KICK else 0.0)  # 3 m down: below every camera's image
            writer.write_frame(t, means=torch.as_tensor(flown, dtype=torch.float32), quats=torch.as_tensor(quats, dtype=torch.float32))
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={landmarks}"]) == 0
    lost = json.loads((run / "landmarks.json").read_text())["lost"]["landmarks"]
    assert all(lost[name]["lost_frames"] == list(range(KICK, FRAMES)) for name in NAMES)
