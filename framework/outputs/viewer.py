"""An interactive 4D viewer of a run in the browser (``mmcsplat view RUN``), on viser.

viser serves a three.js client that draws Gaussian splats, camera frusta and lines, and keeps the page in
step with the Python objects over a websocket; what is written here is only what to show. The scene:

- the run's Gaussians at the chosen frame, as splats (covariance R·diag(s²)·Rᵀ, colour, opacity) or as
  points (``Points`` box);
- a frame slider over the run's frames (labelled by session frame) and a play box at ``fps``;
- every session camera as a frustum with its image at the run's first frame (the held-out ones in orange);
- trails of the tracking figure's Gaussians (2 % of the subject's, the same choice as
  ``mmcsplat render --trajectories``) over their last 10 frames;
- the landmarks of ``RUN/landmarks.csv`` (``mmcsplat landmarks``), when there are some, as larger points
  with their own trails, in the colours of the landmark overlay video;
- a "view from" list of the cameras that moves the browser's camera to one (the held-out one when a
  client connects).
"""

from __future__ import annotations

import contextlib
import io
import time
from pathlib import Path

import numpy as np
import torch

from mmcsplat.outputs.renders import TRAIL_FRAMES, trajectory_colors, trajectory_gaussians
from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.quaternions import quat_to_rotmat
from mmcsplat.storage.landmark_formats import read_landmark_csv
from mmcsplat.storage.run import LANDMARKS_CSV

#: Longest side, in pixels, of the image drawn in a camera's frustum.
FRUSTUM_IMAGE_SIZE = 160
HELDOUT_COLOUR = (255, 140, 0)
TRAIN_COLOUR = (60, 60, 60)
POINT_SIZE = 0.004  # metres
LANDMARK_SIZE = 0.02  # metres: a landmark stands out among the Gaussians


def splat_arrays(params: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """viser's splat arrays of ``GAUSSIAN_PARAMETERS`` tensors: centers [N, 3], covariances [N, 3, 3],
    rgbs [N, 3] in [0, 1] and opacities [N, 1]."""
    rotations = quat_to_rotmat(torch.nn.functional.normalize(params["quats"].detach().float(), dim=-1))
    scales = torch.exp(params["log_scales"].detach().float())
    covariances = rotations @ torch.diag_embed(scales**2) @ rotations.transpose(1, 2)
    return {
        "centers": params["means"].detach().float().numpy(),
        "covariances": covariances.numpy(),
        "rgbs": torch.sigmoid(params["color_logits"].detach().float()).numpy(),
        "opacities": torch.sigmoid(params["opacity_logits"].detach().float())[:, None].numpy(),
    }


def camera_pose(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz [4], position [3]) of ``camera`` in viser's convention: the camera-to-world rotation and the
    centre, OpenCV camera axes (x right, y down, z forward) as mmcsplat's."""
    import viser.transforms as transforms

    return transforms.SO3.from_matrix(camera.R.T).wxyz, camera.center


def vertical_fov(camera: Camera) -> float:
    """The vertical field of view of ``camera`` in radians."""
    return float(2 * np.arctan(0.5 * camera.height / camera.K[1, 1]))


def rig_up(cameras: list[Camera]) -> np.ndarray:
    """The world's up direction as the cameras see it: the mean of their image-up axes (−y)."""
    up = -np.mean([camera.R[1] for camera in cameras], axis=0)
    return up / np.linalg.norm(up)


class RunViewer:
    """A run shown on a viser server: build it, then :meth:`serve_forever` (or drive :meth:`show`)."""

    def __init__(self, run: str | Path, host: str = "127.0.0.1", port: int = 8080, fps: float = 10.0) -> None:
        import viser

        self.states = RunStates(run)
        self.fps = fps
        session = self.states.session
        self.cameras = [session.camera(name) for name in session.camera_names]
        self.heldout = set(self.states.info.heldout_cameras)
        self.trail_indices = trajectory_gaussians(self.states)
        self.landmarks = self._landmarks()
        self._trail_cache: dict[int, np.ndarray] = {}
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a boxed banner; the command prints one line instead
            self.server = viser.ViserServer(host=host, port=port, label=f"mmcsplat {Path(run).name}", verbose=False)
        self.server.scene.set_up_direction(tuple(rig_up(self.cameras)))
        self.handles: dict[str, object] = {}
        self._add_cameras()
        self._add_controls()
        self.server.on_client_connect(lambda client: self._move(client, self.view_from.value))
        self.look_from(self.view_from.value)
        self.show(0)

    def _landmarks(self) -> np.ndarray | None:
        """[T, L, 3] positions of the run's landmarks, or ``None`` without ``RUN/landmarks.csv``."""
        path = self.states.run / LANDMARKS_CSV
        if not path.is_file():
            return None
        _, _, _, positions, _ = read_landmark_csv(path)
        return positions

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def _add_cameras(self) -> None:
        first = self.states.first_frame
        for camera in self.cameras:
            wxyz, position = camera_pose(camera)
            present = self.states.session.present(camera.name)
            image = self._thumbnail(camera, first) if present[first] else None
            heldout = camera.name in self.heldout
            self.handles[f"camera {camera.name}"] = self.server.scene.add_camera_frustum(
                f"/cameras/{camera.name}", fov=vertical_fov(camera), aspect=camera.width / camera.height, scale=0.1,
                thickness=0.004, color=HELDOUT_COLOUR if heldout else TRAIN_COLOUR, image=image, wxyz=wxyz, position=position)

    def _thumbnail(self, camera: Camera, t: int) -> np.ndarray:
        import cv2

        rgb = self.states.session.frame(t, camera.name).rgb
        factor = FRUSTUM_IMAGE_SIZE / max(rgb.shape[:2])
        return cv2.resize(rgb, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA) if factor < 1 else np.asarray(rgb)

    def _add_controls(self) -> None:
        gui = self.server.gui
        first, count = self.states.first_frame, self.states.num_frames
        self.frame = gui.add_slider("frame", min=first, max=first + max(count - 1, 1), step=1, initial_value=first,
                                    disabled=count == 1, hint="session frame shown")
        self.playing = gui.add_checkbox("play", initial_value=count > 1, disabled=count == 1)
        self.points = gui.add_checkbox("points", initial_value=False, hint="Gaussian centres as points instead of splats")
        self.trails = gui.add_checkbox("trails", initial_value=count > 1, hint="the last 10 frames of 2 % of the subject's Gaussians")
        names = [camera.name for camera in self.cameras]
        default = (self.states.info.heldout_cameras or self.states.info.train_cameras)[0]
        self.view_from = gui.add_dropdown("view from", names, initial_value=default)
        for control in (self.frame, self.points, self.trails):
            control.on_update(lambda _: self.show(self.frame.value - first))
        self.view_from.on_update(lambda _: self.look_from(self.view_from.value))

    def look_from(self, name: str) -> None:
        """Put every connected browser's camera at session camera ``name`` and hide its frustum (from
        inside, its image would cover the scene)."""
        for camera in self.cameras:
            self.handles[f"camera {camera.name}"].visible = camera.name != name
        for client in self.server.get_clients().values():
            self._move(client, name)

    def _move(self, client, name: str) -> None:
        camera = next(camera for camera in self.cameras if camera.name == name)
        wxyz, position = camera_pose(camera)
        with client.atomic():
            client.camera.wxyz = wxyz
            client.camera.position = position
            client.camera.fov = vertical_fov(camera)

    def _trail_points(self, k: int) -> np.ndarray:
        if k not in self._trail_cache:
            self._trail_cache[k] = self.states.means(k)[self.trail_indices]
        return self._trail_cache[k]

    def show(self, k: int) -> None:
        """Draw run frame ``k``: its Gaussians, and the trails ending there."""
        arrays = splat_arrays(self.states.params(k))
        scene = self.server.scene
        if self.points.value:
            self.handles["gaussians"] = scene.add_point_cloud("/gaussians", arrays["centers"], (arrays["rgbs"] * 255).astype(np.uint8),
                                                             point_size=POINT_SIZE, point_shape="circle")
        else:
            self.handles["gaussians"] = scene.add_gaussian_splats("/gaussians", **arrays)
        start = max(0, k - TRAIL_FRAMES + 1)
        if self.trails.value and k > start:
            path = np.stack([self._trail_points(j) for j in range(start, k + 1)], axis=1)  # [n, L, 3]
            segments = np.stack([path[:, :-1], path[:, 1:]], axis=2).reshape(-1, 2, 3)
            colours = np.repeat(trajectory_colors(self.trail_indices), k - start, axis=0)
            self.handles["trails"] = scene.add_line_segments("/trails", segments, np.repeat(colours[:, None], 2, axis=1),
                                                             thickness=2.0, thickness_units="screen")
        elif "trails" in self.handles:
            self.handles.pop("trails").remove()
        if self.landmarks is not None:
            self._show_landmarks(k, start)

    def _show_landmarks(self, k: int, start: int) -> None:
        """The landmarks at run frame ``k`` as points, and their paths since frame ``start``."""
        colours = trajectory_colors(np.arange(self.landmarks.shape[1]))
        known = np.all(np.isfinite(self.landmarks[k]), axis=1)
        scene = self.server.scene
        self.handles["landmarks"] = scene.add_point_cloud("/landmarks", self.landmarks[k][known], colours[known],
                                                          point_size=LANDMARK_SIZE, point_shape="circle", precision="float32")
        path = self.landmarks[start : k + 1]
        steps = np.stack([path[:-1], path[1:]], axis=2)  # [n-1, L, 2, 3]
        valid = np.all(np.isfinite(steps), axis=(2, 3))
        if self.trails.value and valid.any():
            segments = steps[valid]
            self.handles["landmark trails"] = scene.add_line_segments(
                "/landmark_trails", segments, np.repeat(np.broadcast_to(colours, valid.shape + (3,))[valid][:, None], 2, axis=1),
                thickness=4.0, thickness_units="screen")
        elif "landmark trails" in self.handles:
            self.handles.pop("landmark trails").remove()

    def step(self) -> None:
        """Advance the frame slider by one, looping (what the play box does each 1 / fps seconds)."""
        first, count = self.states.first_frame, self.states.num_frames
        self.frame.value = first + (self.frame.value - first + 1) % count

    def serve_forever(self) -> None:
        """Play while the play box is ticked, until interrupted; the server stops either way."""
        try:
            while True:
                time.sleep(1.0 / self.fps)
                if self.playing.value and self.states.num_frames > 1:
                    self.step()
        finally:
            with contextlib.redirect_stdout(io.StringIO()):  # viser announces its stop; the command says it once
                self.server.stop()
