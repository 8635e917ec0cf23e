"""``mmcsplat landmarks RUN``: named landmarks carried through a run — ``RUN/landmarks.csv`` and
``RUN/landmarks.json`` — and their movement measures, ``RUN/movement.json`` and ``RUN/movement.csv``.

The landmarks of a source (a ``landmarks`` plugin: TRC or CSV file, triangulated 2D keypoints, a synthetic
capture's joints) over the run's first frames (the fitted one and the next few, :data:`~mmcsplat.scene.landmark_anchors.BIND_FRAMES`
in all, so that one frame's error in the source is outvoted) are bound to the subject's Gaussians at the fitted frame and carried through its frames
(:mod:`mmcsplat.scene.landmark_anchors`). Where the source also knows the landmarks at the frames after those,
the carried ones are scored against them (3D, mm); where a keypoint source gives 2D detections,
the carried landmarks are projected into each camera and scored against them (px), beside the detector's
own disagreement with the source's 3D landmarks. A source of human joints that is not exact also gets its
floor: how near one body of fixed bones can come to it (:mod:`mmcsplat.analysis.reference_floor`). Every
frame, each landmark is judged against the training cameras' subject masks and, where the session has
optical flow, against the images' motion, and the frames where the tracks lost it are recorded
(:mod:`mmcsplat.analysis.lost_landmarks`).
"""

from __future__ import annotations

import csv
import io
import json
import warnings
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.analysis.landmark_binding import confidence, landmark_accuracy
from mmcsplat.analysis.lost_landmarks import LostRule, lost_record, neighbourhoods, off_at_frame, slipped
from mmcsplat.analysis.movement import joint_angle_accuracy, movement_rows, movement_summary
from mmcsplat.analysis.reference_floor import reference_floor
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import KeypointObservations, Landmarks, LandmarkSource
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.landmark_anchors import ANCHORS, BIND_FRAMES, MAX_DISTANCE, SUBJECT_OPACITY, bind_over_frames, carry, subject_gaussians
from mmcsplat.storage.atomic import signals_deferred, write_json_atomic, write_text_atomic
from mmcsplat.storage.completeness import require_finished
from mmcsplat.storage.landmark_formats import CSV_INCOMPLETE_COLUMN, write_landmark_csv
from mmcsplat.storage.locking import run_lock
from mmcsplat.storage.run import LANDMARKS_CSV, LANDMARKS_INFO, MOVEMENT_CSV, MOVEMENT_JSON
from mmcsplat.storage.run_log import run_log
from mmcsplat.storage.session import SessionReader

MIN_KEYPOINT_CONFIDENCE = 0.3  # detections below it are not scored (OpenPose's own cut-off for a visible keypoint)


def pixel_errors(camera: Camera, carried: np.ndarray, reference: np.ndarray, observed: KeypointObservations,
                 source_scale: float = 1.0, floor: np.ndarray | None = None) -> dict[str, Any]:
    """Median and 90th-percentile 2D distances (px of the stored images) in ``camera`` of the carried
    landmarks and of the reference landmarks to the confident detections ``observed`` (both [T, L, 3], the
    observations' frames and names), and of the reference's ``floor`` body where given
    (:mod:`~mmcsplat.analysis.reference_floor`); ``*_source_px`` the same in the recorded video's pixels
    (``source_scale`` of them per stored pixel), which detectors' figures are quoted in."""
    result: dict[str, Any] = {"source_scale": source_scale}
    confident = observed.confidence >= MIN_KEYPOINT_CONFIDENCE
    scored = [("carried_median_px", carried), ("reference_median_px", reference)] + ([("floor_median_px", floor)] if floor is not None else [])
    for key, points in scored:
        known = confident & np.all(np.isfinite(points), axis=-1)
        pixels = camera.project(np.where(np.isfinite(points), points, 0.0).reshape(-1, 3)).reshape(*points.shape[:2], 2)
        distance = np.linalg.norm(pixels - observed.pixels, axis=-1)[known]
        for name, value in ((key, np.median(distance) if distance.size else None),
                            (key.replace("median", "p90"), np.percentile(distance, 90) if distance.size else None)):
            result[name] = None if value is None else float(value)
            result[name.replace("_px", "_source_px")] = None if value is None else float(value) * source_scale
    result["detections"] = int(confident.sum())
    return result


@attrs.frozen
class LandmarkRun:
    """What :func:`track_landmarks` wrote: the carried landmarks, the record of ``landmarks.json`` and the
    measures of ``movement.json``."""

    landmarks: Landmarks
    spread: np.ndarray
    info: dict[str, Any]
    movement: dict[str, Any]


def write_movement(run: Path, summary: dict[str, Any]) -> None:
    """RUN/movement.json, a :func:`~mmcsplat.analysis.movement.movement_summary`, and RUN/movement.csv, its
    scalars one ``subject,measure,value,unit`` row each (an empty value where unknown), and for an incomplete run
    a last row ``run,incomplete,1,``; each written atomically."""
    write_json_atomic(run / MOVEMENT_JSON, summary)
    text = io.StringIO()
    label = [("run", CSV_INCOMPLETE_COLUMN, 1, "")] if summary.get("incomplete") else []
    csv.writer(text, lineterminator="\n").writerows([("subject", "measure", "value", "unit"), *movement_rows(summary), *label])
    write_text_atomic(run / MOVEMENT_CSV, text.getvalue())


def track_landmarks(run: str | Path, source: str, params: dict[str, Any] | None = None, *, keypoints: str | None = None,
                    keypoint_params: dict[str, Any] | None = None, anchors: int = ANCHORS, max_distance: float = MAX_DISTANCE,
                    bind_frames: int | None = None, registry: Registry | None = None, allow_incomplete: bool = False) -> LandmarkRun:
    """Bind the landmarks of the ``landmarks`` plugin ``source`` (built with ``params``) at ``run``'s fitted
    frame, from its first ``bind_frames`` frames (default :data:`BIND_FRAMES`, or 1 for an ``exact`` source;
    fewer when the run has no later frame left to score: all but its last), carry them through its frames,
    score them after those, and write RUN/landmarks.csv and RUN/landmarks.json, and their movement measures
    RUN/movement.json and RUN/movement.csv.
    ``keypoints`` names a second source whose 2D detections score the carried landmarks per camera. An
    unfinished run is refused, or with ``allow_incomplete`` labelled: ``incomplete`` and ``unfinished`` in
    landmarks.json and movement.json, an ``incomplete`` column in landmarks.csv."""
    run = Path(run)
    registry = registry or default_registry()
    states = RunStates(run)
    unfinished = require_finished(run, states.info, allow_incomplete)
    session = states.session
    frames = np.arange(states.first_frame, states.first_frame + states.num_frames)
    plugin: LandmarkSource = registry.create("landmarks", source, **(params or {}))
    reference = plugin.read(session, frames)
    if not np.array_equal(reference.frames, frames):
        raise InputError(f"landmarks {source!r} returned frames {reference.frames[:3].tolist()}… for the run's {frames[:3].tolist()}…")
    bind_frames = bind_frames if bind_frames is not None else 1 if plugin.exact else BIND_FRAMES
    if bind_frames < 1:
        raise InputError(f"landmarks: bind_frames must be ≥ 1, got {bind_frames}")
    bind_frames = max(1, min(bind_frames, len(frames) - 1))
    candidates = subject_gaussians(states.params(0), states.foreground())
    if not len(candidates):
        raise InputError(f"{run}: no subject Gaussian can carry a landmark: none at frame {states.first_frame} is at least "
                         f"{SUBJECT_OPACITY:g} opaque among the subject's (a fit that failed or barely ran: check its PSNR and masks)")
    binding = bind_over_frames(reference.names, reference.positions[:bind_frames], [_state(states.params(k)) for k in range(bind_frames)],
                               candidates, anchors, max_distance)
    if not binding.bound.any():
        nearest = np.nanmin(np.where(np.isfinite(binding.distances), binding.distances, np.nan)) if np.isfinite(binding.distances).any() else None
        raise InputError(f"{run}: no landmark of {reference.source or source} lies within {max_distance * 100:.0f} cm of the subject's Gaussians at "
                         f"frame {states.first_frame}" + (f" (nearest {nearest:.2f} m)" if nearest is not None else " (none is known there)")
                         + ": check the file's units and axes, or raise max_distance")
    with run_lock(run), run_log(run) as log:
        carried = np.empty((len(frames), len(reference.names), 3))
        spread = np.empty((len(frames), len(reference.names)))
        rule, off, judged = LostRule(), np.zeros((len(frames), len(reference.names)), dtype=bool), np.zeros(len(frames), dtype=bool)
        points = np.empty((len(frames), len(reference.names), 1 + binding.anchors.shape[1], 3))
        for k in range(len(frames)):
            means, quats = _state(states.params(k))
            carried[k], spread[k] = carry(binding, means, quats)
            points[k] = neighbourhoods(carried[k], binding.anchors, binding.weights, means)
            off_k = off_at_frame(session, states.info.train_cameras, int(frames[k]), points[k], rule)
            judged[k] = off_k is not None
            off[k] = False if off_k is None else off_k
        slips = slipped(session, states.info.train_cameras, frames, points, carried, rule)
        times = session.frame_times[frames]
        labels = {CSV_INCOMPLETE_COLUMN: np.ones(spread.shape)} if unfinished else {}
        info: dict[str, Any] = {
            "source": source, "params": {key: str(value) if isinstance(value, Path) else value for key, value in (params or {}).items()},
            "described": reference.source, "names": list(reference.names), "frames": [int(frames[0]), int(frames[-1]) + 1],
            "capture_frames": _capture_range(session, frames),
            "anchors": anchors, "max_distance_m": max_distance, "bind_frames": bind_frames, "unbound": binding.unbound,
            "nearest_gaussian_mm": {name: None if not np.isfinite(d) else round(float(d) * 1000, 2) for name, d in zip(binding.names, binding.distances, strict=True)},
            "spread_median_mm": float(np.nanmedian(spread) * 1000) if np.isfinite(spread).any() else None,
            "incomplete": bool(unfinished), "unfinished": unfinished,
        }
        info["lost"] = lost_record(reference.names, binding.bound, frames, off, judged, rule,
                                   {camera.name: rule.tolerance_px(camera) for camera in states.train_cameras}, slips)
        body = None
        if len(frames) > bind_frames and np.isfinite(reference.positions[bind_frames:]).any():
            info["accuracy_3d"] = attrs.asdict(landmark_accuracy(reference.names, carried, reference.positions, bind_frames))
            info["accuracy_joint_angles"] = joint_angle_accuracy(reference.names, carried, reference.positions, bind_frames)
            if not plugin.exact and (floor := reference_floor(reference.names, carried, reference.positions, bind_frames)) is not None:
                info["reference_floor"], body = floor
        if keypoints is not None:
            info["accuracy_2d"] = _accuracy_2d(registry, keypoints, keypoint_params, session, set(states.info.heldout_cameras), frames,
                                               reference, carried, slice(bind_frames if len(frames) > bind_frames else 0, None), body)
        movement = movement_summary(reference.names, times, carried) | {"incomplete": bool(unfinished), "unfinished": unfinished}
        with signals_deferred():  # each file atomic, and a stop never leaves new ones beside old ones
            write_landmark_csv(run / LANDMARKS_CSV, reference.names, session.capture_frames(frames), times, carried,
                               extra={"spread_mm": spread * 1000, "confidence": confidence(spread), **labels})
            write_json_atomic(run / LANDMARKS_INFO, info)
            write_movement(run, movement)
        log.info("landmarks from %s: %d bound, %s unbound; %d frames", source, int(binding.bound.sum()), binding.unbound or "none", len(frames))
        if binding.unbound:
            warnings.warn(f"landmarks {', '.join(binding.unbound)}: no subject Gaussian within {max_distance * 100:.0f} cm at frame "
                          f"{states.first_frame} — left out (NaN), not invented", stacklevel=2)
    return LandmarkRun(Landmarks(reference.names, frames, carried, source=f"carried by {run}"), spread, info, movement)


def _capture_range(session: SessionReader, frames: np.ndarray) -> list[int]:
    """[start, stop, step] of the capture's frame numbers of session ``frames`` (a range): landmarks.csv's rows."""
    first, last = (int(frame) for frame in session.capture_frames([frames[0], frames[-1]]))
    return [first, last + 1, session.capture_start_step[1]]


def _state(params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(means, quats) of one frame's parameters, float64."""
    return tuple(params[name].detach().numpy().astype(np.float64) for name in ("means", "quats"))


def recorded_lost(run: str | Path) -> dict[str, Any] | None:
    """The ``lost`` record of RUN/landmarks.json (:func:`~mmcsplat.analysis.lost_landmarks.lost_record`);
    ``None`` for a run without landmarks or carried before lost landmarks were recorded."""
    path = Path(run) / LANDMARKS_INFO
    return json.loads(path.read_text()).get("lost") if path.is_file() else None


def _accuracy_2d(registry: Registry, name: str, params: dict[str, Any] | None, session: SessionReader, heldout: set[str],
                 frames: np.ndarray, reference: Landmarks, carried: np.ndarray, scored: slice, floor: np.ndarray | None = None) -> dict[str, Any]:
    """Per camera, the 2D errors of the carried and reference landmarks (and the reference's ``floor`` body)
    against the detections of ``name``, over the ``scored`` frames."""
    detector: LandmarkSource = registry.create("landmarks", name, **(params or {}))
    recorded_focal = {name: float(camera.K[0, 0]) for name, camera in session.recorded_cameras().items()}
    result = {}
    for observed in detector.observations(session, frames):
        if not np.array_equal(observed.frames, frames):
            raise InputError(f"keypoints {name!r} of camera {observed.camera!r} cover other frames than the run's")
        shared = [n for n in observed.names if n in reference.names]
        mine = [reference.names.index(n) for n in shared]
        theirs = [observed.names.index(n) for n in shared]
        subset = attrs.evolve(observed, names=shared, frames=observed.frames[scored], pixels=observed.pixels[scored, theirs],
                              confidence=observed.confidence[scored, theirs])
        stored = session.camera(observed.camera)
        recorded = recorded_focal.get(observed.camera)
        result[observed.camera] = {"heldout": observed.camera in heldout,
                                   **pixel_errors(stored, carried[scored, mine], reference.positions[scored, mine], subset,
                                                  recorded / float(stored.K[0, 0]) if recorded else 1.0,
                                                  None if floor is None else floor[scored, mine])}
    if not result:
        raise InputError(f"landmarks {name!r} gives no 2D detections to score against (--keypoints needs a keypoint source, e.g. openpose)")
    return result
