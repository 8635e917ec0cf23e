"""``mmcsplat run`` on a capture that brings its own masks: a small Dynamic3DGaussians capture with ``seg/``
masks, rendered here from a known subject, runs end to end on those masks."""

from __future__ import annotations

import json
from contextlib import redirect_stdout
from io import StringIO
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from fitting_scene import moved, plate, ring_camera, subject

from mmcsplat.cli import main
from mmcsplat.plugin_api.render_contract import RenderCameras
from mmcsplat.storage.session import SessionReader

TRAIN_IDS, TEST_IDS, FRAMES = (0, 1, 2, 3), (4,), 3


def make_rendered_d3dgs(root: Path) -> dict[str, list[np.ndarray]]:
    """A d3dgs capture of :func:`subject` over each camera's plate, seen by five ring cameras (the fifth held
    out, without masks), with the subject's masks in ``seg/`` for the training cameras — each mask the true
    one with a band of 2 columns cut from its left, so that using them is told apart from making new ones.
    Returns the shipped masks by camera name."""
    from mmcsplat.backends.torch_reference import TorchReferenceRenderer

    renderer = TorchReferenceRenderer()
    rig = {cam_id: ring_camera(f"cam_{cam_id:02d}", 2 * np.pi * cam_id / 5, zoom=1) for cam_id in TRAIN_IDS + TEST_IDS}
    shipped: dict[str, list[np.ndarray]] = {}
    for meta, ids in (("train_meta.json", TRAIN_IDS), ("test_meta.json", TEST_IDS)):
        document = {"w": rig[0].width, "h": rig[0].height, "k": [], "w2c": [], "fn": [], "cam_id": []}
        for t in range(FRAMES):
            document["k"].append([rig[cam_id].K.tolist() for cam_id in ids])
            document["w2c"].append([np.vstack([np.hstack([rig[cam_id].R, rig[cam_id].t[:, None]]), [0, 0, 0, 1]]).tolist() for cam_id in ids])
            document["fn"].append([f"{cam_id}/{t:06d}.png" for cam_id in ids])
            document["cam_id"].append(list(ids))
            for cam_id in ids:
                camera = rig[cam_id]
                out = renderer.render(moved(subject(), t), RenderCameras.from_cameras([camera], dtype=torch.float64))
                alpha = out.alpha[0].numpy()
                rgb = np.clip(out.rgb[0].numpy() + (1 - alpha)[..., None] * plate(camera) / 255.0, 0, 1)
                (root / "ims" / str(cam_id)).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(root / "ims" / str(cam_id) / f"{t:06d}.png"), cv2.cvtColor((rgb * 255).round().astype(np.uint8), cv2.COLOR_RGB2BGR))
                if meta == "train_meta.json":
                    mask = alpha > 0.5
                    columns = np.flatnonzero(mask.any(axis=0))
                    mask[:, columns[0] : columns[0] + 2] = False
                    shipped.setdefault(camera.name, []).append(mask)
                    (root / "seg" / str(cam_id)).mkdir(parents=True, exist_ok=True)
                    cv2.imwrite(str(root / "seg" / str(cam_id) / f"{t:06d}.png"), mask.astype(np.uint8) * 255)
        (root / meta).write_text(json.dumps(document))
    return shipped


@pytest.mark.slow
def test_run_uses_the_masks_the_capture_brings(tmp_path):
    capture, out = tmp_path / "capture", tmp_path / "out"
    shipped = make_rendered_d3dgs(capture)
    # cam_03 left out with --cameras: run ingests only the cameras asked for.
    command = ["run", str(capture), "--out", str(out), "--cameras", "cam_00,cam_01,cam_02,cam_04", "--scale", "1", "--set", "fit.iterations=30", "--set", "initializer.visual-hull.num_points=1000",
               "--track-iterations", "2", "--no-progress"]
    with redirect_stdout(StringIO()) as printed:
        assert main(command) == 0
    assert "run: masks: the capture's own, of cam_00, cam_01, cam_02 (held out cam_04 has none" in printed.getvalue()
    assert "mmcsplat run finished" in printed.getvalue()
    record = json.loads((out / "masks.json").read_text())
    assert record["masks"] == "capture" and record["cameras"] == ["cam_00", "cam_01", "cam_02"]
    session = SessionReader(out / "session.zarr")
    assert session.camera_names == ("cam_00", "cam_01", "cam_02", "cam_04")
    assert session.heldout == ("cam_04",) and not session.has("mask", "cam_04")
    for name in session.camera_names[:3]:
        masks = shipped[name]
        for t, mask in enumerate(masks):
            assert np.array_equal(session.frame(t, name).mask, mask)  # the cut band too: not remade
    assert all(session.plate_source(name)["kind"] == "estimated" for name in session.camera_names)
    metrics = json.loads((out / "run" / "metrics.json").read_text())
    assert metrics["heldout_cameras"] == ["cam_04"]
    # No joints: no skeleton to find the body's parts from, so the tracking holds none.
    assert json.loads((out / "run" / "track.json").read_text())["summary"]["body_parts"] is None


def test_run_fits_on_shipped_masks_but_never_on_a_ground_truth(tmp_path):
    import rig_fixtures as rig
    import zarr

    from mmcsplat.pipeline.capture_session import mask_choice
    from mmcsplat.pipeline.ingest import ingest

    source = tmp_path / "capture"
    cameras = rig.make_capture(source, frames=2)
    group = zarr.open_group(str(source / "ground_truth.zarr"), mode="w")
    for camera in cameras:
        group.create_array(f"masks/{camera.name}", data=np.ones((2, camera.height, camera.width), np.uint8))
    choice = mask_choice(ingest(source, tmp_path / "truth.zarr", progress=False), "background")
    assert choice["masks"] == "background" and "its ground truth" in choice["detail"]
    for camera in cameras:
        (source / "masks" / camera.name).mkdir(parents=True)
        for t in range(2):
            cv2.imwrite(str(source / "masks" / camera.name / f"{t}.png"), np.full((camera.height, camera.width), 255, np.uint8))
    choice = mask_choice(ingest(source, tmp_path / "shipped.zarr", holdout=["cam_b"], progress=False), "background")
    assert choice == {"masks": "capture", "cameras": ["cam_a", "cam_b"], "detail": "the capture's own, of cam_a, cam_b"}
