"""Clean plates estimated from the sequence: the temporal median with the subject masked out recovers the
recorded plate wherever the subject uncovered the scene, and is stored as an estimated plate."""

from __future__ import annotations

import numpy as np
import pytest
from fitting_scene import plate, write_session

from mmcsplat.cli.main import main
from mmcsplat.pipeline.plates import estimate_plates, median_plate
from mmcsplat.storage.session import SessionReader


def test_the_median_skips_masked_samples_and_reports_what_it_never_saw():
    frames = np.full((5, 4, 4, 3), 100, np.uint8)
    frames[:2, 0, 0] = 250  # the subject on pixel (0, 0) in two frames: outvoted even unmasked
    frames[:, 1, 1] = 30  # always covered: reported, not invented
    masks = np.zeros((5, 4, 4), bool)
    masks[:, 1, 1] = True
    plate, stable, uncovered = median_plate(frames, masks)
    assert plate[0, 0].tolist() == [100, 100, 100] and plate[2, 2].tolist() == [100, 100, 100]
    assert uncovered[1, 1] and uncovered.sum() == 1 and np.abs(plate[1, 1].astype(int) - 100).max() <= 5  # inpainted from around it
    assert stable[2, 2] and not stable[0, 0]


def test_estimated_plates_match_the_recorded_ones_where_the_subject_moved_off(tmp_path, capsys):
    session = write_session(tmp_path / "s.zarr", frames=6, plates=True)
    recorded = {name: SessionReader(session).plate(name).copy() for name in ("cam_1", "cam_2")}
    assert main(["plates", str(session), "--no-progress"]) == 0  # every camera has a plate: nothing to do
    assert "already has a plate" in capsys.readouterr().out
    estimates = estimate_plates(session, ["cam_1", "cam_2"], replace=True, progress=False)
    reader = SessionReader(session)
    for estimate in estimates:
        camera = reader.camera(estimate.camera)
        assert np.array_equal(recorded[estimate.camera], plate(camera))
        estimated = reader.plate(estimate.camera).astype(int)
        error = np.abs(estimated - plate(camera).astype(int)).max(axis=-1)
        assert np.median(error) == 0 and np.mean(error > 10) < 0.05 + estimate.uncovered_share
        source = reader.plate_source(estimate.camera)
        assert source["kind"] == "estimated" and source["samples"] == 6 and source["masked"]
    assert reader.plate_source("cam_3") == {"kind": "recorded"}


def test_too_short_a_sequence_is_refused(tmp_path):
    session = write_session(tmp_path / "s.zarr", frames=2)
    with pytest.raises(ValueError, match="camera 'cam_0' has 2 frame\\(s\\); a plate from the sequence needs at least 3"):
        estimate_plates(session, progress=False)


def test_plate_segmentation_finds_the_subject_and_consistency_drops_what_one_view_alone_sees(tmp_path):
    from mmcsplat.analysis.visual_hull import consistent_mask
    from mmcsplat.pipeline.segment import segment_session
    from mmcsplat.scene.rig import rig_center, rig_scale

    session = write_session(tmp_path / "s.zarr", frames=2, plates=True)
    segment_session(session, "background", {"method": "plate", "keep": "all"}, progress=False, consistent=True)
    reader = SessionReader(session)
    for camera in reader.camera_names:
        found, truth = reader.frame(0, camera).mask, reader.source_mask(0, camera)
        assert (found & truth).sum() / (found | truth).sum() > 0.8, camera
    views = [(reader.camera(name), reader.source_mask(0, name).copy()) for name in reader.camera_names]
    camera, mask = views[1]
    bystander = mask.copy()
    bystander[:6, :6] = True  # something in one corner of one view only
    center = rig_center(reader.cameras)
    kept = consistent_mask(camera, bystander, views[:1] + views[2:], center, rig_scale(reader.cameras, center))
    assert not kept[:6, :6].any() and kept[mask].mean() > 0.95


def test_plate_segmentation_of_the_synthetic_capture_without_its_masks_matches_the_true_masks(tmp_path):
    """The acceptance bar: masks deleted, the `background` segmenter's defaults over the recorded plates reach
    0.9 IoU with the true masks — the adult's leg in cam_0 and cam_1 (larger there than the infant) dropped
    as off-centre, the outline's half-covered pixels trimmed."""
    import shutil

    from mmcsplat.pipeline.ingest import ingest
    from mmcsplat.pipeline.segment import segment_session
    from mmcsplat.synthetic import SynthConfig, synthesize

    capture = synthesize(tmp_path / "capture", SynthConfig(frames=3), progress=False).out_dir
    bare = tmp_path / "bare"
    shutil.copytree(capture, bare, ignore=shutil.ignore_patterns("ground_truth.zarr"))
    ingest(capture, tmp_path / "truth.zarr", progress=False)
    ingest(bare, tmp_path / "bare.zarr", progress=False)
    assert SessionReader(tmp_path / "bare.zarr").frame(0, "cam_0").mask is None
    segment_session(tmp_path / "bare.zarr", "background", {"method": "plate"}, progress=False)
    truth, found = SessionReader(tmp_path / "truth.zarr"), SessionReader(tmp_path / "bare.zarr")
    scores = {}
    for camera in truth.camera_names:
        ious = [(a & b).sum() / (a | b).sum() for a, b in ((truth.frame(t, camera).mask, found.frame(t, camera).mask) for t in range(3))]
        scores[camera] = float(np.mean(ious))
    assert np.mean(list(scores.values())) >= 0.9 and min(scores.values()) > 0.85, scores
