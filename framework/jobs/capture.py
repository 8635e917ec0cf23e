"""``mmcsplat run CAPTURE --out DIR``: a user's own capture end to end, with defaults that work on a real
rig (docs/real-data.md): ingest → masks → plates → masks refined against them → first-frame fit → track →
evaluate → landmarks → renders → report.

- Masks: with 2D keypoints (``--keypoints DIR``, default ``CAPTURE/pose_2d`` when it exists) the
  skeleton-then-plate path of the ``keypoints`` segmenter; without, the ``background`` segmenter's
  temporal median (a subject that never moves is then lost: keypoints, or a recorded plate, are better).
  A capture ingested with recorded plates keeps them.
- Fit: ``visual-hull-plate`` with the start cube sized from the masks' visual hull (its reach from the
  rig centre plus 10 cm, never below the configuration's), so an adult or a mouse fits like an infant.
- Landmarks: a TRC of joints (``--joints FILE``, default the single ``CAPTURE/*.trc``) bound at the
  fitted frame, scored against its later frames and against the keypoints in every camera.

Every step writes atomically and is skipped on a rerun when its outputs are newer than its inputs, as in
the demo; ``DIR/run.json`` is not this file — the settings are recorded in ``DIR/capture.json`` and a
rerun with other settings is refused.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.jobs.demo import StepTime, fresh, run_step
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import write_json_atomic

SETTINGS_FILE = "capture.json"
DEFAULT_CONFIG = "visual-hull-plate"


@attrs.frozen
class CaptureSettings:
    """What ``mmcsplat run`` does with a capture; ``None`` paths are looked for in the capture folder."""

    calibration: str | None = None
    units: str = "m"
    scale: float = 0.25
    frames: tuple[int | None, int | None, int | None] = (None, None, None)
    holdout: tuple[str, ...] = attrs.field(default=(), converter=tuple)
    keypoints: str | None = None
    joints: str | None = None
    config: str = DEFAULT_CONFIG
    overrides: tuple[str, ...] = attrs.field(default=(), converter=tuple)
    track_iterations: int = 50


@attrs.frozen
class CaptureResult:
    """What a run left: its folder, the metrics, the landmarks' record (empty without joints) and each step's time."""

    out: Path
    run: Path
    metrics: dict[str, Any]
    landmarks: dict[str, Any]
    steps: tuple[StepTime, ...]


def found(capture: Path, given: str | None, pattern: str, what: str) -> Path | None:
    """``given``, else the single ``pattern`` match in ``capture`` (None when there is none)."""
    if given is not None:
        path = Path(given)
        if not path.exists():
            raise InputError(f"{what} {path} does not exist")
        return path.resolve()
    matches = sorted(capture.glob(pattern))
    if len(matches) > 1:
        raise InputError(f"{capture}: several {what} candidates ({', '.join(p.name for p in matches)}); choose one")
    return matches[0].resolve() if matches else None


def run_capture(capture: str | Path, out: str | Path, settings: CaptureSettings = CaptureSettings(), progress: bool = True,
                log: Callable[[str], None] = print) -> CaptureResult:
    """Run every step into ``out`` (module docstring); ``log`` gets one line per step."""
    from mmcsplat.configuration.config import load_config
    from mmcsplat.outputs.landmark_video import render_landmarks
    from mmcsplat.outputs.renders import RunRenderer, render_trajectories
    from mmcsplat.outputs.report import write_report
    from mmcsplat.pipeline.evaluate import METRICS_FILE, evaluate
    from mmcsplat.pipeline.fit import FirstFrameFit
    from mmcsplat.pipeline.ingest import ingest
    from mmcsplat.pipeline.landmarks import LANDMARKS_CSV, LANDMARKS_INFO, MOVEMENT_JSON, track_landmarks
    from mmcsplat.pipeline.plates import estimate_plates
    from mmcsplat.pipeline.run_frames import RunStates
    from mmcsplat.pipeline.segment import segment_session
    from mmcsplat.pipeline.track import TRACK_INFO, track_run
    from mmcsplat.storage.run_info import RUN_INFO
    from mmcsplat.storage.session import SessionReader

    capture, out = Path(capture).resolve(), Path(out).resolve()
    if not capture.is_dir():
        raise InputError(f"capture {capture} is not a folder")
    keypoints = found(capture, settings.keypoints, "pose_2d", "keypoint folder")
    joints = found(capture, settings.joints, "*.trc", "joints TRC file")
    load_config(settings.config, settings.overrides)  # a bad configuration fails before anything runs
    out.mkdir(parents=True, exist_ok=True)
    _check_settings(out, settings)
    session, run = out / "session.zarr", out / "run"
    steps: list[StepTime] = []

    def step(name: str, done: bool, action: Callable[[], object]) -> None:
        steps.append(run_step("run", name, done, action, log))

    def prepare() -> None:
        # Into a hidden sibling renamed into place: a session half segmented is not a session.
        partial = session.with_name(f".{session.name}.partial")
        ingest(capture, partial, calibration=Path(settings.calibration) if settings.calibration else None, units=settings.units,
               frames=slice(*settings.frames), scale=settings.scale, holdout=list(settings.holdout), overwrite=True, progress=progress)
        source = {"name": "openpose", "folder": str(keypoints)} if keypoints else None
        segmenter, first, refined = ("keypoints", {"source": source}, {"source": source, "refine": "plate"}) if source else \
            ("background", {"method": "median"}, {"method": "plate"})
        recorded = any(SessionReader(partial).plate(name) is not None for name in SessionReader(partial).camera_names)
        if not recorded:
            segment_session(partial, segmenter, first, progress=progress)
            estimate_plates(str(partial), None, progress=progress)
        segment_session(partial, segmenter, refined, progress=progress)
        os.replace(partial, session)

    def fit() -> None:
        first = FirstFrameFit(SessionReader(session), load_config(settings.config, settings.overrides), run, progress=progress)
        for grown in first.grown_regions:
            log(f"run: {grown}")
        first.run()

    def landmarks() -> None:
        track_landmarks(run, "trc", {"path": str(joints)}, keypoints="openpose" if keypoints else None,
                        keypoint_params={"folder": str(keypoints)} if keypoints else None)

    step("ingest + masks + plates", session.exists(), prepare)
    step("first-frame fit", (run / RUN_INFO).exists() and json.loads((run / RUN_INFO).read_text())["status"] == "complete", fit)
    step("track (iterative)", fresh([run / "tracks.zarr", run / TRACK_INFO], [run / RUN_INFO]),
         lambda: track_run(run, dynamics="iterative", overrides=[f"dynamics.iterations={settings.track_iterations}"], progress=progress,
                           overwrite=True))
    step("evaluate", fresh([run / METRICS_FILE], [run / TRACK_INFO]), lambda: evaluate(run))
    renders = run / "renders"
    if joints is not None:
        step("landmarks", fresh([run / LANDMARKS_CSV, run / LANDMARKS_INFO, run / MOVEMENT_JSON], [run / TRACK_INFO]), landmarks)
        step("render landmarks", fresh(renders.glob("landmarks_*.mp4"), [run / LANDMARKS_CSV]) and any(renders.glob("landmarks_*.mp4")),
             lambda: render_landmarks(run, _made(renders), progress=progress))
    step("render trajectories", any(renders.glob("trajectories_*.png")) and fresh(renders.glob("trajectories_*.png"), [run / TRACK_INFO]),
         lambda: render_trajectories(RunRenderer(RunStates(run), progress=progress), _made(renders)))
    step("report", fresh([run / "report.html"], [run / METRICS_FILE]), lambda: write_report(run))
    info = json.loads((run / LANDMARKS_INFO).read_text()) if (run / LANDMARKS_INFO).exists() else {}
    return CaptureResult(out, run, json.loads((run / METRICS_FILE).read_text()), info, tuple(steps))


def _made(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _check_settings(out: Path, settings: CaptureSettings) -> None:
    """Record ``settings`` in OUT/capture.json, or refuse when OUT was made with other settings."""
    record = out / SETTINGS_FILE
    wanted = json.loads(json.dumps(attrs.asdict(settings)))
    if record.exists():
        recorded = json.loads(record.read_text())
        if recorded != wanted:
            changed = sorted(key for key in wanted if recorded.get(key) != wanted[key])
            raise InputError(f"{out} was made with other settings ({', '.join(changed)} differ): use another --out, or the same settings to resume")
        return
    write_json_atomic(record, wanted)


def summary(result: CaptureResult) -> str:
    """The closing text of ``mmcsplat run``: outputs, headline figures, warnings, each step's time."""
    metrics = result.metrics
    lines = [f"\nmmcsplat run finished: its steps took {sum(step.seconds for step in result.steps):.0f} s",
             f"  run folder  {result.run}", f"  report      {result.run / 'report.html'}",
             f"  held-out {', '.join(metrics['heldout_cameras']) or '(none)'}: masked PSNR "
             f"{'n/a' if metrics.get('val_masked_psnr') is None else format(metrics['val_masked_psnr'], '.2f') + ' dB'}, "
             f"training views {'n/a' if metrics.get('train_masked_psnr') is None else format(metrics['train_masked_psnr'], '.2f') + ' dB'}; "
             f"{metrics['num_gaussians']} Gaussians"]
    accuracy = result.landmarks.get("accuracy_3d") or {}
    if accuracy.get("median_mm") is not None:
        lines.append(f"  joints: median 3D error {accuracy['median_mm']:.1f} mm against the TRC ({accuracy['still_median_mm']:.1f} mm if held still)")
    lines += [f"  warning: {warning}" for warning in metrics.get("warnings", [])]
    lines += [f"    {step.name:<24} {step.seconds:7.1f} s{'  (already done)' if step.reused else ''}" for step in result.steps]
    return "\n".join(lines)
