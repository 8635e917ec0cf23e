"""The ``parallax`` segmenter (masks from nothing but the calibrated videos) on a small still-trunk
synthetic capture with its masks and plates left out, and the implausible-mask check of the segment step."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from mmcsplat.configuration.registry import default_registry
from mmcsplat.jobs.capture import run_capture
from mmcsplat.pipeline.ingest import ingest
from mmcsplat.pipeline.plates import estimate_plates
from mmcsplat.pipeline.segment import BuiltSegmenter, segment_session
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.segmenters.parallax import floor_normal, recurrence_share, sweep_floor
from mmcsplat.scene.camera import Camera, look_at
from mmcsplat.storage.session import SessionReader
from mmcsplat.synthetic import SynthConfig, synthesize

CONFIG = SynthConfig(frames=3, cameras=8, width=128, height=96, seed=0, motion="still-trunk")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """(a session of the capture's videos and calibration only, the session of the full capture with its true
    masks, the folder of videos and calibration)."""
    root = tmp_path_factory.mktemp("parallax")
    capture = synthesize(root / "capture", CONFIG, progress=False).out_dir
    bare = root / "bare"
    bare.mkdir()
    shutil.copytree(capture / "videos", bare / "videos")
    shutil.copy(capture / "calibration.toml", bare / "calibration.toml")
    ingest(bare, root / "bare.zarr", progress=False)
    ingest(capture, root / "truth.zarr", progress=False)
    return root / "bare.zarr", root / "truth.zarr", bare


def test_floor_found_from_calibration_and_images(sessions):
    plane = default_registry().create("segmenter", "parallax").floor(SessionReader(sessions[0]))
    assert np.degrees(np.arccos(plane.normal @ [0.0, 0.0, 1.0])) < 2  # the mat's normal, z up
    assert abs(plane.offset) < 0.01  # the mat lies at z = 0


def _ious(url, truth: SessionReader) -> np.ndarray:
    """[cameras, frames] IoU of the session's masks at ``url`` with the true ones."""
    session = SessionReader(url)
    ious = []
    for name in session.camera_names:
        masks = [(session.frame(t, name).mask.astype(bool), truth.frame(t, name).mask.astype(bool)) for t in range(CONFIG.frames)]
        ious.append([(mask & true).sum() / (mask | true).sum() for mask, true in masks])
    return np.array(ious)


def test_masks_match_the_truth_in_every_camera_and_plates_refine_them(sessions, tmp_path):
    url = tmp_path / "bare.zarr"
    shutil.copytree(sessions[0], url)
    bare, truth = SessionReader(url), SessionReader(sessions[1])
    assert not bare.has("mask") and all(bare.plate(name) is None for name in bare.camera_names)
    summaries = segment_session(url, "parallax", progress=False)
    assert len(summaries) == CONFIG.cameras and all(summary.plausible for summary in summaries)
    geometric = _ious(url, truth)
    # At 128 × 96 the outline is a large share of the infant; 256 × 192 scores higher (docs/real-data.md).
    assert geometric.min() > 0.65, geometric
    estimate_plates(url, progress=False)  # the median with the parallax masks held out, as `mmcsplat run` does
    segment_session(url, "parallax", {"refine": "plate"}, progress=False)
    refined = _ious(url, truth)
    assert refined.min() > 0.65 and refined.mean() > geometric.mean(), (geometric.mean(), refined.mean())


def test_refine_against_plates_needs_plates(sessions):
    segmenter = default_registry().create("segmenter", "parallax", refine="plate")
    with pytest.raises(InputError, match="mmcsplat plates"):
        next(segmenter.segment(SessionReader(sessions[0]), "cam_0"))


def test_two_cameras_are_refused_saying_how_else_to_give_masks(sessions, tmp_path):
    """Two phones, no keypoints (OpenCap's usual rig): the floor needs a third camera to judge it."""
    ingest(sessions[2], tmp_path / "two.zarr", cameras=["cam_0", "cam_1"], progress=False)
    with pytest.raises(InputError, match=r"needs at least 3 cameras, got 2; give the masks another way: .*--keypoints PATH.*--segmenter NAME"):
        default_registry().create("segmenter", "parallax").floor(SessionReader(tmp_path / "two.zarr"))


def test_a_built_segmenter_refuses_parameters_it_would_not_use(sessions):
    built = BuiltSegmenter("parallax", default_registry().create("segmenter", "parallax"))
    with pytest.raises(ValueError, match="'parallax' is already built"):
        segment_session(sessions[0], built, {"refine": "plate"}, progress=False)
    assert not SessionReader(sessions[0]).has("mask")  # refused before anything is written


def test_implausible_masks_stop_before_anything_is_written(sessions, tmp_path):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(sessions[0], copy)
    before = SessionReader(copy).frame(0, "cam_0").mask
    # A threshold no colour difference reaches: every mask is empty.
    empty = {"method": "median", "threshold": 1000.0}
    with pytest.raises(InputError, match=r"'background' made implausible masks in 8 of 8 cameras \(.*cam_0 0\.0%.*--keypoints"):
        segment_session(copy, "background", empty, progress=False)
    after = SessionReader(copy).frame(0, "cam_0").mask
    assert (before is None and after is None) or np.array_equal(before, after)
    summaries = segment_session(copy, "background", empty, progress=False, check=False)  # asked for: written
    assert all(summary.coverage == 0 and not summary.plausible for summary in summaries)


def test_run_segments_a_capture_of_videos_and_a_calibration_with_parallax(sessions, tmp_path, monkeypatch):
    calls = []

    class Stop(Exception):
        """Ends the run once its masks are chosen."""

    def stop(*args, **kwargs):
        raise Stop

    monkeypatch.setattr("mmcsplat.pipeline.segment.segment_session", lambda url, name, params=None, **kwargs: calls.append((name, params)))
    monkeypatch.setattr("mmcsplat.pipeline.plates.estimate_plates", lambda *args, replace=False, **kwargs: calls.append(("plates", replace)))
    monkeypatch.setattr("mmcsplat.pipeline.fit.FirstFrameFit", stop)
    with pytest.raises(Stop):
        run_capture(sessions[2], tmp_path / "out", progress=False, log=lambda line: None)
    # The refined masks hold the still torso out of the plates once more, and the masks are refined against those.
    assert calls == [("parallax", {}), ("plates", False), ("parallax", {"refine": "plate"}), ("plates", True), ("parallax", {"refine": "plate"})]



def test_a_subject_that_barely_changes_leaves_the_masks_unrestricted(sessions):
    # Three frames, a tenth of a second: the limbs move under a pixel or two at 128 × 96, too little for the
    # cameras to agree on a change, so there is no hull of change and the masks are those without it.
    bare = SessionReader(sessions[0])
    assert default_registry().create("segmenter", "parallax").subject_region(bare) == {}
    with_region, without = (next(default_registry().create("segmenter", "parallax", region=region).segment(bare, "cam_0")) for region in ("change", "none"))
    assert with_region[0] == without[0] == 0 and np.array_equal(with_region[1], without[1]) and with_region[1].any()


def scripted(monkeypatch, images, geometric, region, plate=None):
    """A one-camera session ("cam") of ``images`` (one per frame) with ``plate``, for which the parallax segmenter's
    geometry is scripted: every frame's geometric mask is ``geometric``, the subject region ``region`` ((median,
    hull, pixels whose floor no other camera sees), or None: nothing changed)."""
    parallax = type(default_registry().create("segmenter", "parallax"))
    monkeypatch.setattr(parallax, "_masks", lambda self, session, t: {"cam": geometric})
    monkeypatch.setattr(parallax, "subject_region", lambda self, session: {} if region is None else {"cam": region})
    return SimpleNamespace(present=lambda camera: np.ones(len(images), bool), plate=lambda camera: plate,
                           frame=lambda t, camera: SimpleNamespace(rgb=images[t]))


def test_refinement_leaves_the_hull_where_no_camera_sees_the_floor_unrefined(monkeypatch):
    # A still block that a plate estimated from the sequence took for background: the frame equals the
    # plate, so the plate test drops all of it — except where, within the hull of change, no other camera
    # sees the floor behind it (its upper half, seen against a wall), which is left unrefined.
    image = np.full((12, 12, 3), 90, np.uint8)
    block, hull, unjudged = (np.zeros((12, 12), bool) for _ in range(3))
    block[3:9, 3:9] = True
    hull[1:11, 1:11] = True
    unjudged[1:6, 1:11] = True
    for untrusted, kept in ((unjudged, block & unjudged), (np.zeros_like(block), np.zeros_like(block))):
        session = scripted(monkeypatch, [image], block, (image, hull, hull & untrusted), plate=image)
        (t, mask, _), = default_registry().create("segmenter", "parallax", refine="plate").raw(session, "cam")
        assert t == 0 and np.array_equal(mask, kept)


def test_a_change_where_no_camera_sees_the_floor_is_kept_only_near_its_frame(monkeypatch):
    # Within the hull, a pixel whose floor point no other camera sees is kept where it changed within
    # change_window frames of the mask's, not wherever the subject went at any time of the sequence.
    median = np.full((40, 40, 3), 90, np.uint8)
    moved = median.copy()
    moved[15:25, 15:25] = 200
    images = [moved] + [median] * 7
    hull = np.ones((40, 40), bool)
    session = scripted(monkeypatch, images, np.zeros((40, 40), bool), (median, hull, hull))
    masks = list(default_registry().create("segmenter", "parallax", change_window=2, recurrence=1.0).raw(session, "cam"))
    assert [t for t, _, _ in masks] == list(range(len(images)))
    patch = moved.max(axis=-1) > 90
    first = masks[0][1]
    assert not (first & ~patch).any() and first.sum() >= 0.9 * patch.sum()  # the opening takes the corners
    assert all(np.array_equal(mask, first) for _, mask, _ in masks[1:3])
    assert not any(mask.any() for _, mask, _ in masks[3:])
    # What the window keeps after the change is the wall, whose colour recurs in the other frames: at the default
    # `recurrence` it goes, while the change itself (one frame in eight) stays.
    recurring = [mask for _, mask, _ in default_registry().create("segmenter", "parallax", change_window=2).raw(session, "cam")]
    assert np.array_equal(recurring[0], first) and not any(mask.any() for mask in recurring[1:])


def test_a_still_limb_where_no_camera_sees_the_floor_is_kept_where_it_differs_from_the_plate(monkeypatch):
    # An arm held still for longer than the change window, seen against a wall: the sequence's median shows the
    # arm (no change), so only the plate, which shows the wall, tells it from the background — and only where
    # the floor cannot judge; elsewhere the cameras' geometry decides. Held for a quarter of the sequence, its
    # colour recurs too rarely to be taken for the wall; held throughout, it would be.
    wall = np.full((40, 40, 3), 90, np.uint8)
    image = wall.copy()
    image[10:30, 15:25] = 200
    block, hull, unjudged = (np.zeros((40, 40), bool) for _ in range(3))
    block[10:30, 15:25] = True
    hull[5:35, 5:35] = True
    unjudged[5:20, 5:35] = True
    session = scripted(monkeypatch, [image] * 3 + [wall] * 9, np.zeros((40, 40), bool), (image, hull, unjudged), plate=wall)
    for refine, kept in (("plate", block & unjudged), ("none", np.zeros_like(block))):
        masks = list(default_registry().create("segmenter", "parallax", refine=refine, change_window=0, close_radius=0).raw(session, "cam"))
        assert len(masks) == 12 and all(np.array_equal(mask, kept) for _, mask, _ in masks[:3])


def test_the_wall_that_recurs_beside_the_body_leaves_the_mask_where_no_camera_sees_the_floor(monkeypatch):
    # A plate estimated from a sequence whose first masks missed the subject keeps a ghost of it, and every pixel
    # of the wall differs from the ghost: where the floor cannot judge, the plate test keeps that halo. The wall
    # shows its colour whenever the body is elsewhere; the moving body's colour recurs at a pixel only while the
    # body covers it (here 2 of 10 frames). Pixels whose colour recurs in `recurrence` of the sampled frames go.
    wall = np.full((40, 40, 3), 90, np.uint8)
    images = []
    for t in range(10):
        image = wall.copy()
        image[16:24, 4 * t : 4 * t + 8] = 200
        images.append(image)
    hull = np.ones((40, 40), bool)
    ghost = np.full_like(wall, 150)
    session = scripted(monkeypatch, images, np.zeros((40, 40), bool), (wall, hull, hull), plate=ghost)
    for recurrence in (0.3, 1.0):
        masks = [mask for _, mask, _ in default_registry().create("segmenter", "parallax", refine="plate", recurrence=recurrence,
                                                                   close_radius=0).raw(session, "cam")]
        for image, mask in zip(images, masks, strict=True):
            body = image.max(axis=-1) > 90
            assert np.array_equal(mask, body if recurrence < 1 else hull)  # without the rule, the halo fills the hull


def test_a_body_split_in_an_image_keeps_both_pieces_but_not_the_specks(monkeypatch):
    # Dark shorts before a dark floor cut a standing body at the belt in an image: the voxels and the hull of
    # change already bound the masks, so both pieces are the subject; a speck a twentieth of the body is not.
    pieces = np.zeros((40, 40), bool)
    pieces[2:18, 10:20] = True  # upper body
    pieces[22:38, 10:16] = True  # legs, nearer where the rig's centre projects
    speck = np.zeros_like(pieces)
    speck[30:32, 30:32] = True
    session = scripted(monkeypatch, [np.zeros((40, 40, 3), np.uint8)], pieces | speck, None)
    (t, mask, _), = default_registry().create("segmenter", "parallax", close_radius=0).segment(session, "cam")
    assert t == 0 and np.array_equal(mask, pieces)


def test_the_wall_a_limb_has_just_left_is_dropped_where_it_matches_the_plate(monkeypatch):
    # Where no other camera sees the floor, a pixel that changed within the window is kept at the frames after,
    # when the limb has gone and the wall shows again (the halo about a moving arm): refined against a plate
    # that shows that wall, it stays only where the frame still differs from it by window_threshold (the
    # recurrence rule off here: that wall's colour recurs, so at its default the rule takes it too).
    wall = np.full((40, 40, 3), 90, np.uint8)
    moved = wall.copy()
    moved[15:25, 15:25] = 200
    hull = np.ones((40, 40), bool)
    session = scripted(monkeypatch, [moved] + [wall + 5] * 3, np.zeros((40, 40), bool), (wall, hull, hull), plate=wall)  # then the wall, brighter
    block = moved.max(axis=-1) > 90
    for threshold, share in ((8.0, 0.0), (3.0, 0.9)):
        masks = [mask for _, mask, _ in default_registry().create("segmenter", "parallax", refine="plate", change_window=2, recurrence=1.0,
                                                                   window_threshold=threshold, close_radius=0).raw(session, "cam")]
        assert np.array_equal(masks[0], block) and not masks[3].any()  # the limb differs from the plate; frame 3 is past the window
        for mask in masks[1:3]:  # kept whole but for the corners the change's opening takes, or not at all
            assert not (mask & ~block).any() and (mask.sum() >= share * block.sum() if share else not mask.any())


def test_recurrence_share_counts_the_samples_within_the_threshold_in_every_channel():
    rng = np.random.default_rng(1)
    samples = rng.integers(0, 256, (7, 20, 30, 3), dtype=np.uint8)
    for threshold in (0.5, 9.5, 10.0, 30.0):
        largest = np.abs(samples.astype(int) - samples[2].astype(int)).max(axis=-1)
        assert np.allclose(recurrence_share(samples[2], samples, threshold), (largest < threshold).mean(axis=0))


def test_a_rig_looking_up_at_its_subject_has_no_floor_and_says_what_to_bring_instead():
    """Cameras at desk height looking up at a point above them (Caliscope's own recording looks so at a man at a
    desk, docs/real-data.md): no floor lies below the point they look at, and the error says what run can use."""
    K = np.array([[100.0, 0, 63.5], [0, 100.0, 47.5], [0, 0, 1]])
    centres = [(np.cos(a), np.sin(a), 0.0) for a in np.linspace(0, 2 * np.pi, 4, endpoint=False)]
    cameras = [Camera(f"cam_{k}", 128, 96, K, look_at(c, (0, 0, 0.8)), -look_at(c, (0, 0, 0.8)) @ np.asarray(c))
               for k, c in enumerate(centres)]
    with pytest.raises(InputError, match=r"parallax segmenter: the cameras do not look down at a common point.*bring masks, 2D "
                                         r"keypoints \(run --keypoints\) or clean plates"):
        sweep_floor(cameras, [np.zeros((96, 128, 3), np.uint8)] * 4, floor_normal(cameras))
