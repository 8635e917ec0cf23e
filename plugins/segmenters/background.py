"""``background``: classical background subtraction over the frames of one camera (a static camera, a
moving subject), with morphological clean-up. Frames are streamed from the session; only the median
method holds its sample of frames in memory."""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.segmenters.postprocess import BRIDGE_PX, PostProcessedSegmenter, open_close, present_frames
from mmcsplat.storage.session import SessionReader

#: Each method's default threshold: MOG2's squared Mahalanobis distance, KNN's squared distance, and
#: the median method's largest per-channel difference in grey levels.
DEFAULT_THRESHOLDS = {"mog2": 16.0, "knn": 400.0, "median": 30.0}
#: Samples in each of the KNN model's three sample sets (short-, mid- and long-term; OpenCV's default).
#: A colour is background where it matches ``background_ratio`` of all 3 × KNN_SAMPLES samples.
KNN_SAMPLES = 7


class BackgroundSegmenter(PostProcessedSegmenter):
    """Foreground = what differs from the camera's background model, learnt from the learning frames
    (``learn_frames`` = [start, stop) frame indices, e.g. a few seconds of the empty mat; default: the
    whole sequence, which finds the subject only where it moves).

    ``method``: ``mog2`` or ``knn`` (OpenCV's adaptive mixture / nearest-neighbour models, learnt in
    ``passes`` passes over the learning frames, so the first frame no longer dominates the model, then
    applied frozen to every frame, so early frames are not judged by a half-learnt model) or ``median`` (the per-pixel median of ``samples`` learning frames spread evenly).
    ``background_ratio`` (mog2/knn): a colour seen at a pixel in at least this share of the learning
    frames is background (the median's is 0.5 by definition). ``threshold``: see
    :data:`DEFAULT_THRESHOLDS`. ``history``: frames the mog2/knn model remembers (default: all learning
    frames). ``shadows``: detect shadows (mog2/knn) and count them as background. ``open_radius`` /
    ``close_radius``: morphological opening then closing, pixels (0 skips).
    """

    def __init__(
        self,
        method: str = "mog2",
        threshold: float | None = None,
        background_ratio: float = 0.5,
        learn_frames: tuple[int, int] | None = None,
        history: int | None = None,
        samples: int = 25,
        passes: int = 3,
        shadows: bool = True,
        open_radius: int = 1,
        close_radius: int = 2,
        largest_component: bool = True,
        dilation: int = 0,
        bridge: int = BRIDGE_PX,
    ) -> None:
        super().__init__(largest_component, dilation, bridge)
        if method not in DEFAULT_THRESHOLDS:
            raise InputError(f"background method must be one of {', '.join(DEFAULT_THRESHOLDS)}, got {method!r}")
        if not 0 < background_ratio <= 1:
            raise InputError(f"background_ratio must be in (0, 1], got {background_ratio}")
        if learn_frames is not None and (len(learn_frames) != 2 or not 0 <= learn_frames[0] < learn_frames[1]):
            raise InputError(f"learn_frames must be [start, stop) frame indices with 0 ≤ start < stop, got {learn_frames}")
        if passes < 1:
            raise InputError(f"passes must be ≥ 1, got {passes}")
        if samples < 2:
            raise InputError(f"samples must be ≥ 2 frames, got {samples}")
        if history is not None and history < 1:
            raise InputError(f"history must be ≥ 1 frame, got {history}")
        if open_radius < 0 or close_radius < 0:
            raise InputError(f"open_radius and close_radius must be ≥ 0 pixels, got {open_radius} and {close_radius}")
        self.method = method
        self.threshold = float(DEFAULT_THRESHOLDS[method] if threshold is None else threshold)
        self.background_ratio = float(background_ratio)
        self.learn_frames = None if learn_frames is None else (int(learn_frames[0]), int(learn_frames[1]))
        self.history = history
        self.samples = int(samples)
        self.passes = int(passes)
        self.shadows = bool(shadows)
        self.open_radius, self.close_radius = int(open_radius), int(close_radius)

    def _subtractor(self, num_frames: int) -> cv2.BackgroundSubtractor:
        history = self.history or num_frames
        if self.method == "mog2":
            subtractor = cv2.createBackgroundSubtractorMOG2(history, self.threshold, self.shadows)
            subtractor.setBackgroundRatio(self.background_ratio)
        else:
            subtractor = cv2.createBackgroundSubtractorKNN(history, self.threshold, self.shadows)
            subtractor.setNSamples(KNN_SAMPLES)
            subtractor.setkNNSamples(max(1, round(self.background_ratio * 3 * KNN_SAMPLES)))
        return subtractor

    def _adaptive(self, session: SessionReader, camera: str, learn: np.ndarray, frames: np.ndarray) -> Iterator[np.ndarray]:
        subtractor = self._subtractor(len(learn))
        passes = self.passes
        if self.method == "knn":  # OpenCV's KNN calls every pixel foreground until it has seen 3 × its samples
            passes = max(passes, -(-3 * KNN_SAMPLES // len(learn)))
        for _ in range(passes):
            for t in learn:
                subtractor.apply(session.frame(int(t), camera).rgb)
        for t in frames:  # learning rate 0: every frame is judged by the same, fully learnt model
            yield subtractor.apply(session.frame(int(t), camera).rgb, learningRate=0) == 255  # shadows are 127

    def _median(self, session: SessionReader, camera: str, learn: np.ndarray, frames: np.ndarray) -> Iterator[np.ndarray]:
        picks = np.unique(np.linspace(0, len(learn) - 1, min(self.samples, len(learn))).round().astype(int))
        background = np.median(np.stack([session.frame(int(learn[i]), camera).rgb for i in picks]), axis=0)
        for t in frames:
            difference = np.abs(session.frame(int(t), camera).rgb.astype(np.float32) - background)
            yield difference.max(axis=-1) > self.threshold

    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        frames = present_frames(session, camera)
        learn = frames if self.learn_frames is None else frames[(frames >= self.learn_frames[0]) & (frames < self.learn_frames[1])]
        if len(learn) < 2:
            where = "" if self.learn_frames is None else f" in learn_frames {list(self.learn_frames)}"
            raise InputError(
                f"{session.url}: camera {camera!r} has {len(learn)} frame(s){where}; background subtraction learns from at least 2"
            )
        method = self._median if self.method == "median" else self._adaptive
        masks = method(session, camera, learn, frames)
        for t, mask in zip(frames, masks, strict=True):
            yield int(t), open_close(mask, self.open_radius, self.close_radius), None
