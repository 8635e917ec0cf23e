"""A synthetic capture's joints projected into its cameras are its 2D keypoints (plugins/landmarks/synthetic.py):
triangulated back from the cameras that see them, they are the ground truth again."""

from __future__ import annotations

import numpy as np

from mmcsplat.cli import main
from mmcsplat.plugins.landmarks.synthetic import SyntheticJoints
from mmcsplat.scene.triangulation import triangulate
from mmcsplat.storage.session import SessionReader


def test_synthetic_keypoints_are_the_joints_seen_by_each_camera(tmp_path):
    capture, url = tmp_path / "capture", tmp_path / "session.zarr"
    assert main(["synth", str(capture), "--num-frames", "2", "--width", "32", "--height", "24", "--num-cameras", "4"]) == 0
    assert main(["ingest", str(capture), str(url), "--holdout", "cam_0", "--no-progress"]) == 0
    session = SessionReader(url)
    joints = SyntheticJoints().read(session, [0, 1])
    observed = SyntheticJoints().observations(session, [0, 1])
    assert [o.camera for o in observed] == list(session.camera_names)  # the held-out camera too: guidance drops it itself
    cameras = [session.camera(o.camera) for o in observed]
    for k in range(2):
        pixels = np.stack([o.pixels[k] for o in observed])
        seen = np.stack([o.confidence[k] for o in observed])
        assert set(np.unique(seen)) <= {0.0, 1.0} and (seen.sum(axis=0) >= 2).all()
        for camera, uv, flags in zip(cameras, pixels, seen):
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
            assert np.array_equal(flags > 0, inside)
        np.testing.assert_allclose(triangulate(cameras, pixels, seen), joints.positions[k], atol=1e-6)
