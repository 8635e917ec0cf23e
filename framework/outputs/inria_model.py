"""One frame of a run as a model folder of the reference 3DGS trainer (``mmcsplat export --inria DIR``), the
folder its SIBR viewer and the tools built on that layout open:

- ``DIR/cfg_args``: the trainer's model arguments as the repr of an ``argparse.Namespace`` (``sh_degree=3``,
  ``source_path`` the run's session, ``model_path`` DIR, ``white_background`` whether the run's background
  is white; the other fields the trainer's defaults);
- ``DIR/cameras.json``: every session camera, in session order: ``id`` (its index), ``img_name`` (its
  name), ``width``, ``height``, ``position`` (the camera centre in world coordinates, −Rᵀt), ``rotation``
  (Rᵀ, the camera-to-world rotation as three rows: its columns are the camera's x right, y down and z
  forward axes in world coordinates), ``fy``, ``fx`` (pixels). The format has no principal point nor
  distortion: readers assume the principal point at the image centre;
- ``DIR/point_cloud/iteration_N/point_cloud.ply``: the Gaussians of run frame ``frame`` in the full
  degree-3 PLY layout (:mod:`mmcsplat.outputs.ply`); N is the fit's iteration count (``run.json``), whatever
  the frame.

The folder is written whole beside DIR under a temporary name and renamed into place: an interrupted export
leaves no partial model folder (at most a hidden ``.DIR.*.tmp`` sibling).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mmcsplat.outputs.ply import FULL_SH_DEGREE, write_ply
from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import new_folder, write_json_atomic, write_text_atomic

WHITE = (1.0, 1.0, 1.0)


def camera_entries(cameras: Sequence[Camera]) -> list[dict[str, Any]]:
    """The reference trainer's ``cameras.json`` list for ``cameras`` (module docstring)."""
    return [{
        "id": index,
        "img_name": camera.name,
        "width": camera.width,
        "height": camera.height,
        "position": camera.center.tolist(),
        "rotation": camera.R.T.tolist(),
        "fy": float(camera.K[1, 1]),
        "fx": float(camera.K[0, 0]),
    } for index, camera in enumerate(cameras)]


def cfg_args(source_path: str, model_path: str, white_background: bool) -> str:
    """The reference trainer's ``cfg_args``: its model arguments as a ``Namespace`` repr."""
    return repr(argparse.Namespace(sh_degree=FULL_SH_DEGREE, source_path=source_path, model_path=model_path, images="images",
                                   resolution=-1, white_background=white_background, data_device="cuda", eval=False))


def point_cloud_path(iterations: int) -> Path:
    """Where the reference layout keeps the Gaussians after ``iterations``, relative to the model folder."""
    return Path("point_cloud") / f"iteration_{iterations}" / "point_cloud.ply"


def export_inria(run: str | Path, out: str | Path, frame: int = 0, comments: Sequence[str] = ()) -> Path:
    """Write run frame ``frame`` of ``run`` as the reference trainer's model folder ``out`` (module
    docstring), which must not exist or be empty, with ``comments`` in its PLY's header; returns the path
    of its PLY."""
    states = RunStates(run)
    if not 0 <= frame < states.num_frames:
        raise InputError(f"{states.run}: run frame {frame} does not exist (the run has frames 0 to {states.num_frames - 1})")
    cameras = [states.session.camera(name) for name in states.session.camera_names]
    out = Path(out)
    ply = point_cloud_path(states.info.iterations)
    with new_folder(out) as folder:
        write_text_atomic(folder / "cfg_args", cfg_args(states.info.session, os.path.abspath(out), states.background == WHITE))
        write_json_atomic(folder / "cameras.json", camera_entries(cameras))
        (folder / ply).parent.mkdir(parents=True)
        write_ply(folder / ply, states.params(frame), FULL_SH_DEGREE, comments)
    return out / ply
