"""Held-out-camera evaluation of a fit run: renders every camera of the fitted frame and scores it with
the metric plugins, the way the reference study did (PSNR inside the subject mask on the held-out view)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mmcsplat.analysis.drift import detect_drift
from mmcsplat.analysis.rendered_views import SESSION_MASK, ScoringMask, heldout_mask, render_over, tracked_heldout_scores, training_masks
from mmcsplat.analysis.trajectory_error import evaluate_tracks
from mmcsplat.analysis.visual_hull import FLOATER_MARGIN_PX, dilated, eroded, floater_share, mask_agreement
from mmcsplat.configuration.config import Config, PluginChoice
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.pipeline.landmarks import recorded_lost
from mmcsplat.plugin_api.errors import MissingFileError
from mmcsplat.plugin_api.interfaces import Metric
from mmcsplat.plugin_api.render_contract import gaussians_from_params
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.completeness import ALLOW_INCOMPLETE, UnfinishedRunError, require_finished
from mmcsplat.storage.folds import planned_folds
from mmcsplat.storage.locking import run_lock
from mmcsplat.storage.run import METRICS_FILE, RUN_INFO, TRACKS_DIR
from mmcsplat.storage.run_info import RunInfo
from mmcsplat.storage.tracks import TrackReader
from mmcsplat.training.fitted_run import FittedRun
from mmcsplat.training.plugin_hooks import plugin_hook
from mmcsplat.training.supersampling import run_renderer

#: Above this share of the opacity outside the masks' visual hull, a fit is mostly floaters (the reference
#: study's failure mode; the demo's fits hold 2–5 %).
FLOATER_WARNING = 0.3
#: Below this share of its mask on the other cameras' hull, a camera's calibration or mask is suspect
#: (docs/outputs.md: the synthetic capture's cameras score 0.95–1).
AGREEMENT_WARNING = 0.6


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _floater_share(views: list[tuple[Camera, np.ndarray]], params: dict[str, torch.Tensor]) -> float | None:
    """:func:`~mmcsplat.analysis.visual_hull.floater_share` of the fitted Gaussians against the hull of the
    ``views``' masks (dilated by :data:`~mmcsplat.analysis.visual_hull.FLOATER_MARGIN_PX`); ``None`` without masks."""
    if not views:
        return None
    opacities = torch.sigmoid(params["opacity_logits"].detach()).double().numpy()
    return floater_share(params["means"].detach().double().numpy(), opacities, [(camera, dilated(mask, FLOATER_MARGIN_PX)) for camera, mask in views])


def _mask_agreement(views: list[tuple[Camera, np.ndarray]], center: np.ndarray, radius: float) -> dict[str, float]:
    """Per camera with a non-empty mask, :func:`~mmcsplat.analysis.visual_hull.mask_agreement` with the hull of
    the others' masks (dilated by :data:`~mmcsplat.analysis.visual_hull.FLOATER_MARGIN_PX`), forgiving one other
    view that disagrees when at least three others see a point — so that one camera's wrong extrinsics
    or wrong mask lower its own score, not everyone's. Needs two other cameras at least."""
    grown = [(camera, dilated(mask, FLOATER_MARGIN_PX)) for camera, mask in views]
    scores = {}
    for index, (camera, mask) in enumerate(views):
        others = grown[:index] + grown[index + 1:]
        if len(others) >= 2 and (score := mask_agreement(camera, mask, others, center, radius, tolerance=1 if len(others) >= 3 else 0)) is not None:
            scores[camera.name] = score
    return scores


def failure_signals(floaters: float | None, agreement: dict[str, float]) -> list[str]:
    """One warning per failure signal above its threshold: floaters, cameras off the others' hull."""
    warnings = []
    if floaters is not None and floaters > FLOATER_WARNING:
        warnings.append(f"{floaters:.0%} of the opacity lies outside the subject's visual hull (floaters): the start or pruning region may "
                        "not fit the subject, or too few cameras constrain it — see docs/fit.md")
    for name, score in sorted(agreement.items()):
        if score < AGREEMENT_WARNING:
            warnings.append(f"camera {name!r}: only {score:.0%} of its mask lies on the other cameras' visual hull — its calibration "
                            "(units, a duplicated pose) or its masks are suspect")
    return warnings


def unmasked_signals(unmasked: dict[str, str], tracked: dict[str, dict[str, Any]]) -> list[str]:
    """One warning per held-out camera scored on the full image only: at the fitted frame (``unmasked``,
    camera → reason) and at tracked frames (``tracked``, camera → frames and the first reason)."""
    found = [f"camera {name!r}: no masked score at the fitted frame: {reason}" for name, reason in sorted(unmasked.items())]
    found += [f"camera {name!r}: no masked score at {entry['frames']} tracked frame(s): {entry['reason']}" for name, entry in sorted(tracked.items())]
    return found


def fit_signals(run: Path) -> list[str]:
    """:func:`failure_signals` of a fitted run, from its Gaussians and the session's masks (no rendering)."""
    fitted = FittedRun.load(run)
    info = fitted.info
    views = training_masks(fitted.session, info.frame, fitted.session.camera_names)
    return failure_signals(_floater_share(views, fitted.params), _mask_agreement(views, np.asarray(info.scene_center), info.scene_scale))


def evaluate_run(run: Path, registry: Registry | None = None, backend: str | None = None, ground_truth: Path | None = None,
                 allow_incomplete: bool = False, progress: bool = False, metrics: Sequence[str] = ()) -> dict[str, Any]:
    """Score one run directory and write its metrics.json; returns the metrics. A run with tracks
    (``mmcsplat track``) also gets the tracking metrics of :mod:`mmcsplat.analysis.trajectory_error` (against
    ``ground_truth``, or the one found beside the session's source) and the drift report of
    :mod:`mmcsplat.analysis.drift` (the verdict explained in ``drift_summary``), and the held-out cameras'
    scores at every tracked frame (:func:`~mmcsplat.analysis.rendered_views.tracked_heldout_scores`); one
    with landmarks (``mmcsplat landmarks``) gets their ``lost_landmarks`` record. A
    held-out camera without a mask is scored in the training cameras' hull as it projects there
    (:func:`~mmcsplat.analysis.rendered_views.heldout_mask`), or on the full image only with the reason in
    ``per_camera[…]["unmasked"]`` and ``warnings``. ``floater_share`` is the share of opacity mass outside the
    visual hull of the session's masks at the fitted frame, ``mask_agreement`` per camera the share of its
    mask on the hull of the other cameras' masks (:mod:`mmcsplat.analysis.visual_hull`; low for a camera
    with wrong extrinsics). An unfinished run is refused, or with ``allow_incomplete`` scored with
    ``incomplete`` true; the run's lock is held while it is scored and written, so a fit, track or second
    evaluate at work on it is refused. ``progress`` shows a bar over the tracked frames.

    Metric plugins beyond the built-in PSNR and SSIM, chosen by name — the run's configuration's ``[[metric]]``
    tables, then ``metrics`` — score every camera on the whole image (``NAME``) and inside its scoring mask
    (``masked_NAME``), averaged as ``val_NAME``, ``train_NAME``, ``val_masked_NAME`` and ``train_masked_NAME``."""
    registry = registry or default_registry()
    fitted = FittedRun.load(run)
    unfinished = require_finished(run, fitted.info, allow_incomplete)
    chosen = chosen_metrics(fitted, registry, metrics)
    with run_lock(run):  # no fit, track or second evaluate writes the run while it is scored
        return _score_run(fitted, registry, backend, ground_truth, unfinished, progress, chosen)


#: The metrics every evaluation computes, under these names.
BUILT_IN_METRICS = ("psnr", "ssim")


def chosen_metrics(fitted: FittedRun, registry: Registry, names: Sequence[str]) -> dict[str, Metric]:
    """The metric plugins of the run's configuration (``[[metric]]`` tables, with parameters) and of ``names``
    (at their defaults), by name, built; the built-in ones left out (every evaluation has them)."""
    choices = Config(f"run {fitted.path}", fitted.info.config_values).plugins("metric")
    choices += [PluginChoice("metric", name, {}) for name in names if name not in {choice.name for choice in choices}]
    return {choice.name: registry.create("metric", choice.name, **choice.params) for choice in choices if choice.name not in BUILT_IN_METRICS}


def _score_run(fitted: FittedRun, registry: Registry, backend: str | None, ground_truth: Path | None, unfinished: list[str],
               progress: bool, chosen: dict[str, Metric]) -> dict[str, Any]:
    """:func:`evaluate_run` of the loaded run ``fitted`` (whose lock the caller holds), its ``unfinished`` work labelled."""
    run, info, params = fitted.path, fitted.info, fitted.params
    session = fitted.session
    renderer = run_renderer(info, registry, backend)
    psnr = registry.create("metric", "psnr")
    ssim = registry.create("metric", "ssim")
    gaussians = gaussians_from_params(params)
    frame = info.frame
    views = training_masks(session, frame, session.camera_names)
    train_views = [(camera, mask) for camera, mask in views if camera.name in info.train_cameras]
    center = np.asarray(info.scene_center)
    scores: dict[str, dict[str, list[float]]] = {"val": {}, "train": {}}
    per_camera = {}
    unmasked = {}
    # A moving camera's poses are cameras present at one frame each: only those imaging the fitted frame are scored.
    names = [name for name in (*info.train_cameras, *info.heldout_cameras) if session.present(name)[frame]]
    for name in names:
        split = "train" if name in info.train_cameras else "val"
        data = session.frame(frame, name)
        rgb = render_over(renderer, gaussians, session.camera(name), fitted.backdrop(name))
        if split == "train":  # training views are scored through their learnt colour correction
            index = info.train_cameras.index(name)
            rgb = rgb * fitted.camera_scale[index] + fitted.camera_offset[index]
        prediction = rgb.clamp(0, 1).double().numpy()
        target = data.rgb.astype(np.float64) / 255.0
        camera_scores = {"psnr": psnr(prediction, target), "ssim": ssim(prediction, target)}
        scoring = (heldout_mask(data.mask, session.camera(name), frame, train_views, center, info.scene_scale) if split == "val"
                   else ScoringMask(data.mask, SESSION_MASK if data.mask is not None else None))
        masked = scoring.mask if scoring.mask is not None and scoring.mask.any() else None
        for metric_name, metric in chosen.items():
            with plugin_hook("metric", metric_name, "__call__"):
                camera_scores[metric_name] = float(metric(prediction, target))
                if masked is not None:
                    camera_scores[f"masked_{metric_name}"] = float(metric(prediction, target, masked))
        if masked is not None:
            camera_scores["masked_psnr"] = psnr(prediction, target, masked)
            interior = eroded(masked, 1)
            if interior.any():
                camera_scores["interior_masked_psnr"] = psnr(prediction, target, interior)
        elif split == "val":
            unmasked[name] = scoring.reason or f"its mask is empty at frame {frame}"
        for key, value in camera_scores.items():
            scores[split].setdefault(key, []).append(value)
        described = {"mask": scoring.source, "mask_coverage": scoring.coverage, "unmasked": unmasked.get(name)}
        per_camera[name] = {"split": split, **camera_scores, **{key: value for key, value in described.items() if value is not None}}
    floaters = _floater_share(views, params)
    agreement = _mask_agreement(views, center, info.scene_scale)
    metrics = {
        "val_masked_psnr": _mean(scores["val"].get("masked_psnr", [])),
        "val_psnr": _mean(scores["val"].get("psnr", [])),
        "val_ssim": _mean(scores["val"].get("ssim", [])),
        "train_masked_psnr": _mean(scores["train"].get("masked_psnr", [])),
        "val_interior_masked_psnr": _mean(scores["val"].get("interior_masked_psnr", [])),
        "train_interior_masked_psnr": _mean(scores["train"].get("interior_masked_psnr", [])),
        "train_psnr": _mean(scores["train"].get("psnr", [])),
        "num_gaussians": int(params["means"].shape[0]),
        "floater_share": floaters,
        "mask_agreement": agreement,
        "warnings": failure_signals(floaters, agreement) + unmasked_signals(unmasked, {}),
        "iterations": info.iterations,
        "wall_s": info.wall_s,
        "status": info.status,
        "incomplete": bool(unfinished),
        "unfinished": unfinished,
        "heldout_cameras": list(info.heldout_cameras),
        "per_camera": per_camera,
        "metrics": list(chosen),
        **{f"{split}_{key}": _mean(scores[split].get(key, [])) for key in (*chosen, *(f"masked_{name}" for name in chosen))
           for split in ("val", "train")},
    }
    if (Path(run) / TRACKS_DIR).exists():
        fitted.require_own_tracks(TrackReader(run))
        fitted.require_tracked_frames(TrackReader(run))
        backdrops = {name: fitted.backdrop(name) for name in info.heldout_cameras}
        tracked = tracked_heldout_scores(TrackReader(run), session, info.heldout_cameras, info.train_cameras, renderer, psnr, backdrops,
                                         center, info.scene_scale, progress)
        metrics.update(tracked)
        metrics["warnings"] += unmasked_signals({}, tracked["tracked_val_unmasked"])
        metrics.update(evaluate_tracks(Path(run), session, info.heldout_cameras, ground_truth))
        report = detect_drift(TrackReader(run), session, info.train_cameras)
        metrics.update(drift=report.drift, drift_summary=report.explain(), drift_since_frame=report.since, drift_gaussians=len(report.drifted),
                       drift_per_frame=report.counts, drift_foreground=report.foreground)
    if (lost := recorded_lost(run)) is not None:
        metrics["lost_landmarks"] = lost
    write_json_atomic(Path(run) / METRICS_FILE, metrics)
    return metrics


def fold_runs(run: Path) -> list[Path]:
    """The fold sub-directories of a leave-one-camera-out run that hold a fit (those of its plan,
    :mod:`mmcsplat.storage.folds`, else every one), or ``[run]`` for a single fit."""
    run = Path(run)
    if (run / RUN_INFO).exists():
        return [run]
    fits = sorted(path for path in run.iterdir() if (path / RUN_INFO).exists()) if run.is_dir() else []
    planned = planned_folds(run)
    if planned is not None:
        folds = [run / name for name in planned if (run / name / RUN_INFO).exists()]
    else:  # folds fitted before plans were written: each holds out the camera it is named after (a `run` folder's run/ does not)
        folds = [path for path in fits if RunInfo.read(path).heldout_cameras == (path.name,)]
    if not folds:
        hint = f": it holds the run {fits[0]}, evaluate that" if len(fits) == 1 else ""
        raise MissingFileError(f"{run} holds no fit run ({RUN_INFO}) nor fold runs{hint}")
    return folds


def missing_folds(run: Path) -> list[str]:
    """What of the planned folds of ``run`` has no fit yet, each with what to do (empty without a plan)."""
    missing = [name for name in planned_folds(run) or () if not (Path(run) / name / RUN_INFO).exists()]
    return [f"fold {name} has no fit ({Path(run) / name / RUN_INFO} is missing: killed before its first checkpoint, or not reached): "
            "run the same `mmcsplat fit --folds` again" for name in missing]


def evaluate(run: Path, registry: Registry | None = None, backend: str | None = None, ground_truth: Path | None = None,
             allow_incomplete: bool = False, progress: bool = False, metrics: Sequence[str] = ()) -> dict[str, Any]:
    """Evaluate a run or every fold of a leave-one-camera-out run; folds are averaged into RUN/metrics.json.
    A planned fold without a fit is refused like an unfinished fold, or with ``allow_incomplete`` left out
    and named in ``unfinished``. ``progress`` shows a bar over each run's tracked frames; ``metrics`` as
    :func:`evaluate_run` takes them."""
    runs = fold_runs(run)
    if runs == [Path(run)]:
        return evaluate_run(Path(run), registry, backend, ground_truth, allow_incomplete, progress, metrics)
    missing = missing_folds(run)
    if missing and not allow_incomplete:
        raise UnfinishedRunError(f"run {run} is unfinished: {'; '.join(missing)} (or pass {ALLOW_INCOMPLETE} to label the outputs incomplete)")
    folds = {path.name: evaluate_run(path, registry, backend, ground_truth, allow_incomplete, progress, metrics) for path in runs}
    summary: dict[str, Any] = {}
    for key in ("val_masked_psnr", "val_psnr", "val_ssim", "train_masked_psnr", "val_interior_masked_psnr", "train_interior_masked_psnr", "train_psnr", "num_gaussians", "floater_share", "iterations", "wall_s"):
        values = [m[key] for m in folds.values() if m[key] is not None]
        summary[key] = _mean(values)
    summary["val_masked_psnr_std"] = float(np.std([m["val_masked_psnr"] for m in folds.values() if m["val_masked_psnr"] is not None] or [np.nan]))
    summary["unfinished"] = missing + [f"fold {name}: {problem}" for name, m in folds.items() for problem in m["unfinished"]]
    summary["incomplete"] = bool(summary["unfinished"])
    summary["folds"] = folds
    with run_lock(Path(run)):
        write_json_atomic(Path(run) / METRICS_FILE, summary)
    return summary
