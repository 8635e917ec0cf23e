"""Optical flow per session: computed by `mmcsplat flow`, stored in the session, read pair by pair, resumed
after an interruption, and replaced atomically."""

from __future__ import annotations

import numpy as np
import pytest
from rig_fixtures import ring_cameras

from mmcsplat.cli.main import main
from mmcsplat.pipeline.flow import (
    CROP_ALIGN,
    CROP_MARGIN,
    DEFAULT_PRESET,
    DisFlow,
    compute_flow,
    consistency,
    flow_complete,
    mask_arrays,
    method_record,
)
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.session import SessionReader, SessionUpdater, SessionWriter
from mmcsplat.storage.session.flow import FlowWriter, SessionFlow

SHIFT = (3.0, -2.0)  # pixels per frame: (u, v)
FRAMES = 4


def texture(width: int, height: int) -> np.ndarray:
    """Smooth random texture, larger than the frames, that DIS follows well."""
    import cv2

    noise = np.random.default_rng(0).random((height + 40, width + 40)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 2.0)
    return (255 * (smooth - smooth.min()) / np.ptp(smooth)).astype(np.uint8)


def write_session(path, absent=(), mask=None, width=96, height=72):
    """Frames of a texture moving by SHIFT, with masks ``mask(t)`` (default: empty, so the flow covers the image)."""
    cameras = ring_cameras(["a", "b", "c"], width=width, height=height, distortion=(0, 0, 0, 0, 0))
    base = texture(width, height)
    with SessionWriter(path, cameras=cameras, num_frames=FRAMES, fps=30.0, heldout=["c"]) as writer:
        for camera in cameras:
            for t in range(FRAMES):
                if (camera.name, t) in absent:
                    continue
                u, v = 20 - round(SHIFT[0] * t), 20 - round(SHIFT[1] * t)  # the content moves by +SHIFT
                grey = base[v : v + height, u : u + width]
                masked = np.zeros((height, width), bool) if mask is None else mask(t)
                writer.write_frame(camera.name, t, np.repeat(grey[..., None], 3, axis=-1), mask=masked)
    return path


def test_flow_follows_a_known_shift_and_is_stored(tmp_path, capsys):
    session = write_session(tmp_path / "s.zarr")
    assert not SessionFlow(session).available
    assert main(["flow", str(session), "--no-progress"]) == 0
    assert "a: 3 pairs of frames" in capsys.readouterr().out
    assert main(["flow", str(session), "--no-progress"]) == 0
    assert "a: 3 pairs of frames already computed" in capsys.readouterr().out
    flow = SessionFlow(session)
    assert flow.available and flow.cameras_with_flow == ("a", "b")  # the held-out camera's images stay out
    assert flow.method == method_record(DEFAULT_PRESET, mask_arrays(SessionReader(session), ("a", "b")))
    pair = flow.pair(1, "a")
    inner = (slice(10, -10), slice(10, -10))
    assert np.allclose(np.median(pair.forward[inner], axis=0), SHIFT, atol=0.2)
    assert np.allclose(np.median(pair.backward[inner], axis=0), [-SHIFT[0], -SHIFT[1]], atol=0.2)
    assert np.median(pair.forward_confidence[inner]) > 0.8
    with pytest.raises(InputError, match="'c' has no optical flow"):
        flow.pair(0, "c")
    SessionReader(session).frame(0, "a")  # the session still reads


def test_pairs_with_an_absent_frame_are_skipped(tmp_path):
    session = write_session(tmp_path / "s.zarr", absent={("b", 2)})
    summaries = {summary.camera: summary for summary in compute_flow(session, progress=False)}
    assert summaries["a"].computed == 3 and summaries["b"].computed == 1
    with pytest.raises(InputError, match="no flow from frame 1 to 2"):
        SessionFlow(session).pair(1, "b")


def test_an_interrupted_computation_resumes_and_is_invisible(tmp_path):
    session = write_session(tmp_path / "s.zarr")
    with pytest.raises(KeyboardInterrupt):
        method = method_record(DEFAULT_PRESET, mask_arrays(SessionReader(session), ("a", "b")))
        with FlowWriter(session, method=method, cameras=("a", "b")) as writer:
            pair = compute_pair_of(session, 0)
            writer.write("a", 0, pair)
            raise KeyboardInterrupt
    assert not SessionFlow(session).available
    summaries = {summary.camera: summary for summary in compute_flow(session, progress=False)}
    assert (summaries["a"].computed, summaries["a"].kept) == (2, 1)
    assert np.allclose(SessionFlow(session).pair(0, "a").forward, pair.forward, atol=0.01)


def test_another_preset_replaces_the_flow_and_updates_keep_it(tmp_path):
    session = write_session(tmp_path / "s.zarr")
    compute_flow(session, progress=False)
    first = SessionFlow(session)._group_name
    compute_flow(session, preset="ultrafast", progress=False)
    flow = SessionFlow(session)
    assert flow.method["preset"] == "ultrafast" and flow._group_name != first
    assert first not in set(flow._group.group_keys())  # the replaced flow is deleted
    with SessionUpdater(session) as updater:
        for t in range(FRAMES):
            updater.write("a", "mask", t, np.ones((72, 96), bool))
    assert SessionFlow(session).available
    assert not flow_complete(session, preset="ultrafast")  # cut around the old masks: computed again


def test_the_flow_is_computed_around_the_subject_only(tmp_path):
    size = {"width": 224, "height": 160}
    reach = CROP_MARGIN + CROP_ALIGN  # the box's widest reach beyond the masks

    def square(t):  # the subject: a square moving with the texture
        mask = np.zeros((size["height"], size["width"]), bool)
        top, left = 72 + round(SHIFT[1] * t), 100 + round(SHIFT[0] * t)
        mask[top : top + 12, left : left + 12] = True
        return mask

    whole = compute_pair_of(write_session(tmp_path / "whole.zarr", **size), 1)
    session = write_session(tmp_path / "cropped.zarr", mask=square, **size)
    compute_flow(session, progress=False)
    pair = SessionFlow(session).pair(1, "a")
    for flow, expected, subject in ((pair.forward, whole.forward, square(1)), (pair.backward, whole.backward, square(2))):
        assert np.abs(flow[subject] - expected[subject]).max() < 0.05  # float16 storage
        assert np.allclose(np.median(flow[subject], axis=0), np.median(expected[subject], axis=0), atol=0.01)
    near = np.zeros_like(square(1))
    near[72 - 2 - reach : 84 + reach, 100 - reach : 112 + 3 * 2 + reach] = True
    assert pair.forward_confidence[~near].max() == 0 and pair.backward_confidence[~near].max() == 0
    assert not np.any(pair.forward[~near]) and not np.any(pair.backward[~near])
    assert np.median(pair.forward_confidence[square(1)]) > 0.8


def test_an_incomplete_flow_is_refused(tmp_path):
    session = write_session(tmp_path / "s.zarr")
    with pytest.raises(InputError, match="the flow is incomplete"):
        with FlowWriter(session, method=method_record("medium"), cameras=("a",)):
            pass
    assert not SessionFlow(session).available


def test_confidence_drops_where_forward_and_backward_disagree():
    forward = np.full((8, 8, 2), 1.0, np.float32)
    assert consistency(forward, -forward)[2:6, 2:6].min() > 0.99
    assert consistency(forward, forward)[2:6, 2:6].max() < 0.01
    assert consistency(forward, -forward)[:, -1].max() == 0  # the flow leaves the image


def test_the_default_flow_follows_a_thin_limb_moving_its_own_width():
    # A textured bar 4 px wide moves 4 px over a static texture, as a fast foot does at the demo's size:
    # DIS `medium` reports a tenth of the motion there (0.4 px), the default all of it (3.97 px).
    background = texture(96, 72)[:72, :96] // 2 + 64
    bar = texture(40, 32)[:32, :4]
    first, second = background.copy(), background.copy()
    first[20:52, 40:44], second[20:52, 44:48] = bar, bar
    on_bar = (slice(22, 50), slice(41, 43))
    assert np.median(DisFlow(DEFAULT_PRESET).calc(first, second)[on_bar][..., 0]) == pytest.approx(4.0, abs=0.2)
    assert np.median(DisFlow("medium").calc(first, second)[on_bar][..., 0]) < 3.0


def test_a_pairs_backward_flow_on_a_second_thread_is_the_same_flow():
    # compute_flow runs the backward flow beside the forward one when a core is free: it must not change it.
    from concurrent.futures import ThreadPoolExecutor

    background = texture(96, 72)[:72, :96]
    second = np.roll(background, (2, 3), axis=(0, 1))
    dis = DisFlow(DEFAULT_PRESET)
    serial = dis.both(background, second)
    with ThreadPoolExecutor(max_workers=1) as pool:
        threaded = dis.both(background, second, pool)
    assert np.median(serial[0][10:60, 10:80], axis=(0, 1)) == pytest.approx([3.0, 2.0], abs=0.2)
    for alone, beside in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(alone, beside)


def compute_pair_of(session, t):
    from mmcsplat.pipeline.flow import flow_pair, grey

    reader = SessionReader(session)
    return flow_pair(grey(reader.frame(t, "a").rgb), grey(reader.frame(t + 1, "a").rgb), DisFlow(DEFAULT_PRESET))
