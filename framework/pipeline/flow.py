"""Dense optical flow between consecutive frames of every training camera, computed once per session.

OpenCV's DIS flow (Kroeger et al. 2016) on the stored, undistorted images turned grey, forward (t → t+1)
and backward (t+1 → t). Besides OpenCV's presets, ``fine`` (the default) tunes ``medium`` for a fast thin
limb: ``medium`` stops one pyramid level above full resolution and smooths with 8-pixel patches and a
variational refinement, so a foot a few pixels wide that moves about its width is reported at under half
its motion; ``fine`` matches 6-pixel patches down to full resolution, without the refinement, on the images
upsampled ×2 (cubic), the flow then averaged back to the images' pixels. Each pixel's confidence comes
from forward–backward consistency: following the forward flow and then the backward flow from where it
lands should return to the pixel; the confidence is exp(−|f + b|² / (0.01 (|f|² + |b|²) + 0.5)), the
tolerance of Sundaram et al. (2010) that grows with the motion, and 0 where the forward flow leaves the
image. Where the session has masks, DIS runs only on a box around the subject (the union of both frames'
masks, widened by :data:`CROP_MARGIN` and aligned to :data:`CROP_ALIGN` pixels): the flow is read only
at the subject, and outside the box it is absent (zero, confidence 0); without masks, or with both empty,
on the whole image. The preset was chosen by measurement (docs/dynamics.md, "Preset `fine`"). Frames stream through
the session reader two at a time, so memory does not grow with the sequence; the result is stored in the
session (:mod:`mmcsplat.storage.session.flow`), resumably. Each DIS flow runs on one thread; a pair's
backward flow runs beside its forward one while the other processes leave a core free (the training's
thread policy, :mod:`mmcsplat.training.threads`, decides), which halves the flow's time on an idle
2-core machine.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.session.flow import FlowPair, FlowWriter, SessionFlow, pair_present
from mmcsplat.training.threads import thread_policy


@attrs.frozen
class DisSettings:
    """How DIS is run: an OpenCV preset (``cv2.DISOPTICAL_FLOW_PRESET_<BASE>``), optionally with its finest
    pyramid level, patch size and variational refinement iterations replaced, on the images upsampled by
    ``upsample``."""

    base: str
    finest_scale: int | None = None
    patch_size: int | None = None
    refinement_iterations: int | None = None
    upsample: int = 1


#: The DIS presets: OpenCV's three and ``fine`` (module docstring). cv2 is imported only to compute, so that
#: the command line starts without it.
SETTINGS = {
    "ultrafast": DisSettings("ultrafast"),
    "fast": DisSettings("fast"),
    "medium": DisSettings("medium"),
    "fine": DisSettings("medium", finest_scale=0, patch_size=6, refinement_iterations=0, upsample=2),
}
PRESETS = tuple(SETTINGS)
#: The default preset: on the synthetic fast kicks its flow lifted to 3D predicts the moving joints' next
#: positions best (docs/dynamics.md, "Preset `fine`").
DEFAULT_PRESET = "fine"


#: Pixels added on every side of the subject's masks before the flow is computed on that box: room for the
#: patches and the coarse pyramid levels around a limb at the masks' edge (docs/dynamics.md, "Flow on the
#: subject only").
CROP_MARGIN = 32
#: The box's edges are rounded outwards to multiples of this many pixels, so that its pyramid levels halve evenly.
CROP_ALIGN = 16


@attrs.frozen
class FlowSummary:
    """What :func:`compute_flow` did for one camera: pairs computed now, pairs kept (from an interrupted run,
    or a complete flow of the same method), the CPU seconds per pair computed now and the share of their
    pixels with a forward confidence above one half (``None`` when none was computed)."""

    camera: str
    computed: int
    kept: int
    cpu_s_per_pair: float | None
    confident_share: float | None


def method_record(preset: str, masks: Mapping[str, str | None] | None = None) -> dict:
    """How the flow is made, as stored with it (a different record means recomputing): the preset and its
    settings, so that flow stored before a preset's settings changed is recomputed, and the crop around the
    subject with the mask arrays ``masks`` (camera → array name, from :func:`mask_arrays`) it was cut
    from, so that flow cut around masks a later segmentation replaced is recomputed."""
    import cv2

    return {"name": "dis", "preset": preset, "settings": attrs.asdict(SETTINGS[preset]), "opencv": cv2.__version__,
            "confidence": "forward-backward", "crop": {"margin": CROP_MARGIN, "align": CROP_ALIGN, "masks": dict(masks or {})}}


def mask_arrays(session: SessionReader, cameras: Sequence[str]) -> dict[str, str | None]:
    """Camera → the name of the mask array the flow's crop is cut from (``None``: no masks, whole image)."""
    return {name: session.field_array("mask", name) for name in cameras}


def subject_box(first_mask: np.ndarray | None, second_mask: np.ndarray | None) -> tuple[slice, slice] | None:
    """The rows and columns to compute the flow on: the union of both [H, W] masks widened by
    :data:`CROP_MARGIN` and aligned to :data:`CROP_ALIGN` within the image; ``None`` (the whole image)
    without masks or where both are empty."""
    if first_mask is None or second_mask is None:
        return None
    union = np.logical_or(first_mask, second_mask)
    rows, columns = np.flatnonzero(union.any(axis=1)), np.flatnonzero(union.any(axis=0))
    if not rows.size:
        return None

    def span(low: int, high: int, size: int) -> slice:
        start = max(0, (low - CROP_MARGIN) // CROP_ALIGN * CROP_ALIGN)
        stop = min(size, -(-(high + 1 + CROP_MARGIN) // CROP_ALIGN) * CROP_ALIGN)
        return slice(start, stop)

    return span(rows[0], rows[-1], union.shape[0]), span(columns[0], columns[-1], union.shape[1])


def grey(rgb: np.ndarray) -> np.ndarray:
    """[H, W] uint8 luminance of [H, W, 3] RGB."""
    import cv2

    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def consistency(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """[H, W] confidence of ``forward`` [H, W, 2] given ``backward`` [H, W, 2] of the other frame (module docstring)."""
    import cv2

    height, width = forward.shape[:2]
    columns, rows = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    landed_x, landed_y = columns + forward[..., 0], rows + forward[..., 1]
    returned = cv2.remap(backward, landed_x, landed_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    error = np.sum((forward + returned) ** 2, axis=-1)
    tolerance = 0.01 * (np.sum(forward**2, axis=-1) + np.sum(returned**2, axis=-1)) + 0.5
    inside = (landed_x >= 0) & (landed_x <= width - 1) & (landed_y >= 0) & (landed_y <= height - 1)
    return np.where(inside, np.exp(-error / tolerance), 0.0).astype(np.float32)


class DisFlow:
    """OpenCV's DIS flow run as ``preset`` (one of :data:`PRESETS`), each flow on one thread: the machine may
    be shared, so a pair's backward flow takes a second thread only when :meth:`both` is given one."""

    def __init__(self, preset: str) -> None:
        import cv2

        if preset not in SETTINGS:
            raise InputError(f"unknown DIS preset {preset!r}: use one of {', '.join(PRESETS)}")
        settings = SETTINGS[preset]
        cv2.setNumThreads(1)
        self.preset = preset
        self.dis: cv2.DISOpticalFlow = cv2.DISOpticalFlow.create(getattr(cv2, f"DISOPTICAL_FLOW_PRESET_{settings.base.upper()}"))
        if settings.finest_scale is not None:
            self.dis.setFinestScale(settings.finest_scale)
        if settings.patch_size is not None:
            self.dis.setPatchSize(settings.patch_size)
        if settings.refinement_iterations is not None:
            self.dis.setVariationalRefinementIterations(settings.refinement_iterations)
        self.upsample = settings.upsample
        self._twin: DisFlow | None = None

    def calc(self, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        """[H, W, 2] float32 flow in pixels from grey image ``first`` to ``second`` [H, W] uint8."""
        import cv2

        if self.upsample == 1:
            return self.dis.calc(first, second, None)
        factor = self.upsample
        larger = [cv2.resize(image, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC) for image in (first, second)]
        flow = self.dis.calc(*larger, None)
        height, width = first.shape
        return cv2.resize(flow, (width, height), interpolation=cv2.INTER_AREA) / np.float32(factor)

    def both(self, first: np.ndarray, second: np.ndarray, pool: Executor | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The forward and backward flow between ``first`` and ``second``; with ``pool`` the backward one on its
        thread, by a second DIS instance (an instance holds its pyramids, so two threads cannot share one; OpenCV
        releases the GIL while it computes). The flows are the same either way."""
        if pool is None:
            return self.calc(first, second), self.calc(second, first)
        if self._twin is None:
            self._twin = DisFlow(self.preset)
        backward = pool.submit(self._twin.calc, second, first)
        return self.calc(first, second), backward.result()


def flow_pair(first: np.ndarray, second: np.ndarray, dis: DisFlow, box: tuple[slice, slice] | None = None,
              pool: Executor | None = None) -> FlowPair:
    """The forward and backward flow between two grey images, with their confidences; with ``box`` (from
    :func:`subject_box`) computed inside it only, zero with confidence 0 outside; with ``pool`` the backward
    flow on its thread (:meth:`DisFlow.both`)."""
    inside = box or (slice(None), slice(None))
    first_part, second_part = np.ascontiguousarray(first[inside]), np.ascontiguousarray(second[inside])
    forward, backward = dis.both(first_part, second_part, pool)
    parts = (forward, backward, consistency(forward, backward), consistency(backward, forward))
    if box is None:
        return FlowPair(*parts)
    whole = []
    for part in parts:
        field = np.zeros(first.shape + part.shape[2:], dtype=np.float32)
        field[box] = part
        whole.append(field)
    return FlowPair(*whole)


def flow_complete(url: str | os.PathLike, cameras: Sequence[str] | None = None, preset: str = DEFAULT_PRESET) -> bool:
    """Whether the session holds the flow of ``cameras`` (default: its training cameras) computed with ``preset``."""
    stored = SessionFlow(url)
    session = SessionReader(url, cache_bytes=0)
    names = tuple(cameras) if cameras else session.train_cameras
    return stored.method == method_record(preset, mask_arrays(session, names)) and stored.cameras_with_flow == names


def compute_flow(url: str | os.PathLike, cameras: Sequence[str] | None = None, preset: str = DEFAULT_PRESET, *,
                 progress: bool = True) -> list[FlowSummary]:
    """Compute and store the flow of ``cameras`` (default: the session's training cameras), resuming an
    interrupted computation of the same preset and keeping a complete one; returns what was done per camera."""
    from tqdm import tqdm

    dis = DisFlow(preset)
    session = SessionReader(url, cache_bytes=0)
    names = tuple(cameras) if cameras else session.train_cameras
    for name in names:
        session.camera(name)
    if flow_complete(url, names, preset):
        return [FlowSummary(name, 0, int(pair_present(session.present(name)).sum()), None, None) for name in names]
    summaries = []
    threads = thread_policy()  # a pair's two flows on two threads while the other processes leave a core free
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="dis") as pool, \
            FlowWriter(url, method=method_record(preset, mask_arrays(session, names)), cameras=names) as writer:
        for name in names:
            pairs = writer.missing(name)
            kept = int(pair_present(session.present(name)).sum()) - len(pairs)
            confident, previous, began = [], None, time.process_time()
            for t in tqdm(pairs, desc=f"flow {name}", unit="pair", disable=not progress):
                first = previous[1] if previous is not None and previous[0] == t else session.frame(int(t), name)
                second = session.frame(int(t) + 1, name)
                pair = flow_pair(grey(first.rgb), grey(second.rgb), dis, subject_box(first.mask, second.mask),
                                 pool if threads.update() > 1 else None)
                writer.write(name, int(t), pair)
                confident.append(float((pair.forward_confidence > 0.5).mean()))
                previous = (t + 1, second)
            cpu = (time.process_time() - began) / len(pairs) if len(pairs) else None
            summaries.append(FlowSummary(name, len(pairs), kept, cpu, float(np.mean(confident)) if confident else None))
    return summaries

