"""Flow slip: a body rises through a session whose optical flow follows it exactly; a landmark whose
neighbourhood rises with it hardly slips, one whose anchors stay where they were slips by the rise and is
held off from the frame its slip passes the rule's 50 mm, in every camera. Over a long run whose flow has a
small bias, the slip over the rule's window keeps a followed landmark quiet and still finds one left behind
within a few frames of the limb starting to move."""

from __future__ import annotations

import numpy as np
from rig_fixtures import ring_cameras, write_blank_session

from mmcsplat.analysis.landmark_flow import WINDOW, flow_slip, slip_mm
from mmcsplat.analysis.lost_landmarks import LostRule, lost_line, lost_record, slipped, voted
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.session.flow import FlowPair, FlowWriter, SessionFlow

CAMERAS = ring_cameras(["a", "b", "c"], width=160, height=120, distortion=(0, 0, 0, 0, 0))
FRAMES = 6
RISE = np.array([0.0, 0.0, 0.025])  # metres per frame: 20 mm across each camera's image (seen from 39° above)
BODY = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01], [-0.01, 0.0, 0.0]])


LONG_FRAMES, STILL_UNTIL = 48, 40  # the long run: the body still, then rising from frame 40
BIAS = np.array([0.15, 0.0])  # px a pair the long run's flow is off by: about 2 mm at the body, 100 mm over 45 pairs


def body(t: int) -> np.ndarray:
    return BODY + RISE * t


def kick(t: int) -> np.ndarray:
    """The long run's body: still until :data:`STILL_UNTIL`, then rising."""
    return BODY + RISE * max(0, t - STILL_UNTIL)


def capture(tmp_path, motion=body, frames: int = FRAMES, bias: np.ndarray = np.zeros(2)) -> SessionReader:
    """A session of blank images whose flow moves every pixel as the ``motion``'s first point moves (a
    textured body filling the view), off by ``bias`` px each pair."""
    url = tmp_path / "s.zarr"
    write_blank_session(url, CAMERAS, frames)
    with FlowWriter(url, method={"name": "exact"}, cameras=[camera.name for camera in CAMERAS]) as writer:
        for camera in CAMERAS:
            for t in range(frames - 1):
                step = camera.project(motion(t + 1)[:1]) - camera.project(motion(t)[:1]) + bias
                forward = np.broadcast_to(step, (120, 160, 2)).astype(np.float32)
                confidence = np.ones((120, 160), np.float32)
                writer.write(camera.name, t, FlowPair(forward, -forward, confidence, confidence))
    return SessionReader(url)


def neighbourhoods() -> tuple[np.ndarray, np.ndarray]:
    """([T, 2, P, 3] neighbourhoods, [T, 2, 3] landmarks): the first follows the body, the second stays put."""
    follows = np.stack([body(t) for t in range(FRAMES)])
    stays = np.repeat(body(0)[None], FRAMES, axis=0)
    points = np.stack([follows, stays], axis=1)
    return points, points[:, :, 0]


def test_a_landmark_left_behind_slips_by_the_motion_one_that_follows_does_not(tmp_path):
    session = capture(tmp_path)
    points, carried = neighbourhoods()
    slip = flow_slip(SessionFlow(session.url), CAMERAS, np.arange(FRAMES), points)
    assert np.isnan(slip[:, 0]).all() and np.nanmax(slip[:, 1:, 0]) < 0.05  # float16 flow, and the body's points a centimetre apart
    expected = np.stack([[np.linalg.norm(camera.project(body(t)[:1]) - camera.project(body(0)[:1])) for t in range(1, FRAMES)] for camera in CAMERAS])
    np.testing.assert_allclose(slip[:, 1:, 1], expected, atol=0.05)
    off = slipped(session, [camera.name for camera in CAMERAS], np.arange(FRAMES), points, carried, LostRule())
    assert not off[:, 0].any()
    assert off[:, 1].tolist() == [False, False, False, True, True, True]  # 40, then 60 mm of 50 at frames 2, 3


def test_the_record_says_the_flow_found_it(tmp_path):
    session = capture(tmp_path)
    points, carried = neighbourhoods()
    rule = LostRule()
    slips = slipped(session, [camera.name for camera in CAMERAS], np.arange(FRAMES), points, carried, rule)
    record = lost_record(("follows", "stays"), np.array([True, True]), np.arange(FRAMES), np.zeros((FRAMES, 2), bool), np.ones(FRAMES, bool),
                         rule, {}, slips)
    assert record["flow_judged"] and record["landmarks"]["follows"] == {"first_lost_frame": None, "lost_frames": [], "found_by": []}
    assert record["landmarks"]["stays"] == {"first_lost_frame": 3, "lost_frames": [3, 4, 5], "found_by": ["flow"]}
    assert lost_line(record) == "lost (off the subject masks or slipped from the optical flow in most cameras): stays from frame 3 (3 frames; flow)"


def test_a_session_without_flow_is_judged_on_the_masks_alone(tmp_path):
    url = tmp_path / "s.zarr"
    write_blank_session(url, CAMERAS, 2)
    points, carried = neighbourhoods()
    assert slipped(SessionReader(url), ["a", "b"], np.arange(2), points[:2], carried[:2], LostRule()) is None
    record = lost_record(("follows",), np.array([True]), np.arange(2), np.zeros((2, 1), bool), np.ones(2, bool), LostRule(), {})
    assert not record["flow_judged"]
    assert lost_line(record) == ("no landmark lost: every carried landmark followed the subject masks (2 frames judged)"
                                 " — masks only: `mmcsplat flow SESSION` adds the flow check")


def test_over_a_long_run_a_followed_landmark_is_never_flagged_and_one_left_behind_is_within_the_window(tmp_path):
    session = capture(tmp_path, kick, LONG_FRAMES, BIAS)
    follows = np.stack([kick(t) for t in range(LONG_FRAMES)])
    stays = np.repeat(kick(0)[None], LONG_FRAMES, axis=0)
    points = np.stack([follows, stays], axis=1)
    frames, names = np.arange(LONG_FRAMES), [camera.name for camera in CAMERAS]
    rule = LostRule()
    # Summed from the first frame, the bias alone would carry the followed landmark past 50 mm.
    summed = flow_slip(SessionFlow(session.url), CAMERAS, frames, points, window=LONG_FRAMES)
    assert voted(slip_mm(summed, CAMERAS, points[:, :, 0]) > rule.slip_mm, np.isfinite(summed), rule)[:, 0].any()
    off = slipped(session, names, frames, points, points[:, :, 0], rule)
    assert not off[:, 0].any()
    assert not off[:STILL_UNTIL + 1, 1].any() and off[STILL_UNTIL + 3:, 1].all()  # 20, 40, then 60 mm of the rise past 50
    lost = lost_record(("follows", "stays"), np.array([True, True]), frames, np.zeros((LONG_FRAMES, 2), bool), np.ones(LONG_FRAMES, bool), rule, {}, off)
    assert lost["landmarks"]["follows"]["first_lost_frame"] is None
    assert lost["landmarks"]["stays"]["first_lost_frame"] == STILL_UNTIL + 3 < STILL_UNTIL + WINDOW
    assert lost["rule"]["slip_window"] == WINDOW
