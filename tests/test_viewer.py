"""mmcsplat view: the run's scene on a viser server — checked through viser's API, drawn by a real headless
browser (Debian's chromium; skipped without it), and stopped by Ctrl-C."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch
from render_fixtures import add_tracks, expected_means, fitted_run

from mmcsplat.outputs.renders import TRAIL_FRAMES
from mmcsplat.outputs.viewer import RunViewer, camera_pose, splat_arrays
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.fitted_run import FittedRun

FRAMES = 4
CHROMIUM = Path("/usr/bin/chromium")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return add_tracks(fitted_run(tmp_path_factory.mktemp("view"), iterations=1), FRAMES)


@pytest.fixture
def viewer(run):
    viewer = RunViewer(run, port=free_port())
    yield viewer
    viewer.server.stop()


def test_splats_are_the_run_gaussians(run):
    params = FittedRun.load(run).params
    arrays = splat_arrays(params)
    eigenvalues = np.sort(np.linalg.eigvalsh(arrays["covariances"]), axis=1)
    np.testing.assert_allclose(eigenvalues, np.sort(torch.exp(2 * params["log_scales"]).numpy(), axis=1), rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(arrays["rgbs"], torch.sigmoid(params["color_logits"]).numpy(), atol=1e-6)
    assert arrays["opacities"].shape == (len(arrays["centers"]), 1)


def test_frusta_sit_where_the_cameras_look(run):
    import viser.transforms as transforms

    session = SessionReader(FittedRun.load(run).info.session)
    for camera in session.cameras:
        wxyz, position = camera_pose(camera)
        np.testing.assert_allclose(position, camera.center, atol=1e-9)
        forward = transforms.SO3(wxyz).apply(np.array([0.0, 0.0, 1.0]))
        np.testing.assert_allclose(forward, camera.R[2], atol=1e-9)  # the optical axis in world coordinates


def test_the_scene_follows_the_frame_slider(viewer, run):
    session = viewer.states.session
    assert sorted(key for key in viewer.handles if key.startswith("camera ")) == sorted(f"camera {name}" for name in session.camera_names)
    assert viewer.frame.min == 0 and viewer.frame.max == FRAMES - 1 and viewer.view_from.value == "cam_0"
    assert not viewer.handles["camera cam_0"].visible and viewer.handles["camera cam_1"].visible
    viewer.look_from("cam_2")  # what choosing it in "view from" does: the frustum looked through is hidden
    assert [viewer.handles[f"camera {name}"].visible for name in session.camera_names] == [name != "cam_2" for name in session.camera_names]
    viewer.frame.value = FRAMES - 1  # what a user's drag does: the callback redraws
    viewer.show(FRAMES - 1)
    np.testing.assert_allclose(viewer.handles["gaussians"].centers, expected_means(run, FRAMES - 1), atol=1e-5)
    trails = viewer.handles["trails"].points
    assert trails.shape == (len(viewer.trail_indices) * min(FRAMES - 1, TRAIL_FRAMES - 1), 2, 3)
    np.testing.assert_allclose(trails[-1, 1], expected_means(run, FRAMES - 1)[viewer.trail_indices[-1]], atol=1e-5)
    viewer.step()
    assert viewer.frame.value == 0  # the play box loops
    viewer.points.value = True
    viewer.show(0)
    assert "trails" not in viewer.handles and type(viewer.handles["gaussians"]).__name__ == "PointCloudHandle"


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium (.ci/run installs it: apt-get install chromium)")
def test_a_browser_draws_the_scene(viewer, tmp_path):
    connected = []
    viewer.server.on_client_connect(lambda client: connected.append(client.client_id))
    import cv2

    # Chromium's virtual time runs ahead of the viewer's real-time websocket, so on a busy machine the
    # screenshot can come before the scene arrives: a fresh page with a longer budget is tried then.
    for attempt, budget_ms in enumerate((15000, 40000, 90000)):
        shot = tmp_path / f"view{attempt}.png"
        subprocess.run(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={tmp_path / f'profile{attempt}'}", "--window-size=900,700", f"--virtual-time-budget={budget_ms}",
             f"--screenshot={shot}", viewer.url],
            capture_output=True, text=True, timeout=180, check=True)
        assert len(connected) == attempt + 1, "the page never opened its websocket to the viewer"
        centre = cv2.imread(str(shot))[150:550, 250:650].reshape(-1, 3)
        drawn = np.any(np.abs(centre.astype(int) - np.median(centre, axis=0)) > 40, axis=1)
        if drawn.mean() > 0.01:
            break
    else:
        pytest.fail(f"the canvas is blank in all {attempt + 1} pages ({drawn.mean():.2%} of the last one's centre drawn)")
    assert len(np.unique(centre[drawn], axis=0)) > 50, "the drawing has too few colours to be splats and images"


def test_landmarks_are_shown_with_their_trails(run, tmp_path):
    import shutil

    from mmcsplat.storage.landmark_formats import write_landmark_csv

    shutil.copytree(run.parent, tmp_path / "project")  # the run keeps its session beside it (a relative path)
    copy = tmp_path / "project" / run.name
    positions = np.stack([expected_means(copy, t)[:2] for t in range(FRAMES)]).astype(np.float64)  # two Gaussians as landmarks
    positions[1, 1] = np.nan  # one unknown at frame 1
    write_landmark_csv(copy / "landmarks.csv", ("LWrist", "RWrist"), np.arange(FRAMES), np.arange(FRAMES) / 30.0, positions)
    viewer = RunViewer(copy, port=free_port())
    try:
        viewer.show(FRAMES - 1)
        np.testing.assert_allclose(viewer.handles["landmarks"].points, positions[-1], atol=1e-5)
        # Frames 0→1 and 1→2 of RWrist are broken by its unknown frame 1: 2 × 3 steps, less those 2.
        assert viewer.handles["landmark trails"].points.shape == (2 * (FRAMES - 1) - 2, 2, 3)
    finally:
        viewer.server.stop()


def test_the_command_serves_until_ctrl_c(run):
    port = free_port()
    command = [sys.executable, "-m", "mmcsplat.cli.main", "view", str(run), "--port", str(port)]
    # Ctrl-C as a terminal delivers it: a test run started in the background (nohup, `&`) ignores SIGINT, and
    # a child would inherit that and never stop.
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = process.stdout.readline()
        assert f"http://127.0.0.1:{port}" in line, line + process.stderr.read() if process.poll() is not None else line
        assert f"{FRAMES} frame(s)" in line
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        time.sleep(0.5)
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert "viewer stopped" in out and "Traceback" not in err
