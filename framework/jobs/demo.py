"""``mmcsplat demo``: the main job on the built-in synthetic infant capture, end to end, in one folder.

Synthesize the capture, ingest and segment it, fit the first frame, track the sequence, evaluate on the
held-out camera (tracking errors against the capture's ground truth), carry the infant's joints through
the tracks as landmarks (scored against the true joints; exported as CSV and TRC), render the tracking
figure, the landmark overlay and a novel-view path, and write the HTML report — each step with the
functions its own command calls.

A rerun resumes: a step is skipped when its outputs exist and are newer than what they are made from.
Every output appears atomically, so a half-done step never reads as done. ``OUT/demo.json`` records
the settings once a step has succeeded; a rerun with other settings is then refused rather than mixing
two demos in one folder. The steps run through :mod:`mmcsplat.pipeline.steps`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.analysis.lost_landmarks import lost_line
from mmcsplat.configuration.config import Config, load_config
from mmcsplat.pipeline.steps import SettingsRecord, Step, StepTime, fit_complete, fresh, made_in_place, run_steps
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.run import (
    LANDMARKS_CSV,
    LANDMARKS_INFO,
    LANDMARKS_TRC,
    METRICS_FILE,
    MOVEMENT_JSON,
    NOVEL_VIDEO,
    RENDERS_DIR,
    REPORT_FILE,
    RUN_INFO,
    TRACK_INFO,
    TRACKS_DIR,
)

SETTINGS_FILE = "demo.json"
#: The demo's steps a frame of ``iterative`` where its configuration names none, rather than the method's ``auto``
#: (100 at the synthetic capture's 30 fps): its infant moves slowly, and 100 gain 0.2 mm on the moving joints
#: (3.3 against 3.5 mm) for twice the tracking time.
DEMO_ITERATIONS = 50


@attrs.frozen
class DemoSettings:
    """What the demo makes: ``frames`` frames of ``width`` × ``height`` from the synthetic capture's
    cameras, fitted with configuration ``config`` after ``overrides`` on renderer ``backend`` (default:
    the configuration's), tracked with ``track_iterations`` iterations per frame of ``iterative``
    (default: the configuration's [dynamics] table, else :data:`DEMO_ITERATIONS`: :func:`tracking_choice`)."""

    frames: int = 30
    width: int = 256
    height: int = 192
    config: str = "masked-plate"
    overrides: tuple[str, ...] = attrs.field(default=(), converter=tuple)
    backend: str | None = None
    track_iterations: int | None = None


@attrs.frozen
class DemoPaths:
    """Where the demo writes: :meth:`under` an output folder."""

    out: Path
    capture: Path
    session: Path
    run: Path
    tracks: Path
    track_info: Path
    metrics: Path
    landmarks_csv: Path
    landmarks_info: Path
    landmarks_trc: Path
    movement: Path
    renders: Path
    trajectories_video: Path
    trajectories_strip: Path
    landmarks_video: Path
    novel: Path
    report: Path

    @classmethod
    def under(cls, out: Path) -> DemoPaths:
        """The paths in ``out``: the run is OUT/first-frame, its renders and report where the commands put them."""
        from mmcsplat.synthetic.defaults import SYNTHETIC_HELDOUT

        run = out / "first-frame"
        renders = run / RENDERS_DIR
        trajectories = renders / f"trajectories_{SYNTHETIC_HELDOUT[0]}"
        return cls(out, out / "capture", out / "session.zarr", run, run / TRACKS_DIR, run / TRACK_INFO, run / METRICS_FILE,
                   run / LANDMARKS_CSV, run / LANDMARKS_INFO, run / LANDMARKS_TRC, run / MOVEMENT_JSON, renders, trajectories.with_suffix(".mp4"),
                   trajectories.with_suffix(".png"), renders / f"landmarks_{SYNTHETIC_HELDOUT[0]}.mp4", renders / NOVEL_VIDEO,
                   run / REPORT_FILE)


@attrs.frozen
class DemoResult:
    """What a demo run left: its paths, the tracking method, the metrics and each step's time."""

    paths: DemoPaths
    method: str
    iterations: int | None
    metrics: dict[str, Any]
    landmarks: dict[str, Any]
    steps: tuple[StepTime, ...]


def tracking_choice(config: Config, iterations: int | None) -> tuple[str, list[str]]:
    """(dynamics method, tracking overrides): the method the configuration's [dynamics] table names, else
    ``iterative``, at the table's settings, else the method's defaults (those ``mmcsplat run`` tracks with:
    on the demo they follow the infant more closely and twice as fast as the fit's means rate at 150
    iterations a frame, docs/performance.md, "The demo") with :data:`DEMO_ITERATIONS` a frame;
    ``iterations`` per frame of ``iterative`` when given."""
    table = config.get("dynamics") or {}
    method = table.get("name") or "iterative"
    if iterations is None:
        return method, [f"dynamics.iterations={DEMO_ITERATIONS}"] if method == "iterative" and "iterations" not in table else []
    if method != "iterative":
        raise InputError(f"{config.source}: --track-iterations sets the iterative method's iterations per frame, "
                         f"but its [dynamics] table chooses {method!r}: set dynamics.KEY values instead")
    return method, [f"dynamics.iterations={iterations}"]


def run_demo(out: Path, settings: DemoSettings = DemoSettings(), progress: bool = True,
             log: Callable[[str], None] = print) -> DemoResult:
    """Run every step of the demo into ``out`` (created), skipping those already done; ``log`` gets one
    line per step."""
    from mmcsplat.outputs.landmark_export import export_landmarks
    from mmcsplat.outputs.landmark_video import render_landmarks
    from mmcsplat.outputs.renders import RunRenderer, render_novel, render_trajectories
    from mmcsplat.outputs.report import write_report
    from mmcsplat.pipeline.evaluate import evaluate
    from mmcsplat.pipeline.fit import FirstFrameFit
    from mmcsplat.pipeline.ingest import ingest
    from mmcsplat.pipeline.landmarks import track_landmarks
    from mmcsplat.pipeline.run_frames import RunStates
    from mmcsplat.pipeline.segment import segment_session
    from mmcsplat.pipeline.track import track_run
    from mmcsplat.storage.session import SessionReader
    from mmcsplat.synthetic.defaults import SYNTHETIC_HELDOUT, SYNTHETIC_SEGMENTER
    from mmcsplat.synthetic.synthesize import SynthConfig, synthesize

    if settings.frames < 2:
        raise InputError(f"the demo tracks the frames after the first: it needs at least 2 frames, not {settings.frames}")
    paths = DemoPaths.under(Path(out).resolve())  # absolute: the session records its capture, the run its session
    config = load_config(settings.config, settings.overrides)  # fail early on a bad configuration
    synth = SynthConfig(frames=settings.frames, width=settings.width, height=settings.height)
    method, track_overrides = tracking_choice(config, settings.track_iterations)
    if track_overrides:  # the fit records the tracking's steps in run.json too, so `mmcsplat track DEMO/run` re-tracks as the demo did
        config = load_config(settings.config, [*settings.overrides, *track_overrides])
    paths.out.mkdir(parents=True, exist_ok=True)
    run, fitted = paths.run, paths.run / RUN_INFO

    def ingest_and_segment(partial: Path) -> None:
        ingest(paths.capture, partial, holdout=list(SYNTHETIC_HELDOUT), overwrite=True, progress=progress)
        # The synthetic capture ships subject masks; segmenting keeps their central component per view.
        segment_session(partial, SYNTHETIC_SEGMENTER, progress=progress)

    def renderer() -> RunRenderer:
        return RunRenderer(RunStates(run), backend=settings.backend, progress=progress)

    def landmarks() -> None:
        track_landmarks(run, "synthetic")
        export_landmarks(run, trc=paths.landmarks_trc)

    def render_trajectories_step() -> None:
        paths.renders.mkdir(exist_ok=True)
        render_trajectories(renderer(), paths.renders, SYNTHETIC_HELDOUT[0])

    steps = [
        Step("synthesize", lambda: (paths.capture / "calibration.toml").exists(), lambda: synthesize(paths.capture, synth, progress=progress)),
        # Into a hidden sibling renamed into place: an interrupted segmentation is not a session.
        Step("ingest + segment", paths.session.exists, lambda: made_in_place(paths.session, ingest_and_segment)),
        Step("first-frame fit", lambda: fit_complete(run),
             lambda: FirstFrameFit(SessionReader(paths.session), config, run, backend=settings.backend, progress=progress).run()),
        Step(f"track ({method})", lambda: fresh([paths.tracks, paths.track_info], [fitted]),
             lambda: track_run(run, dynamics=method, overrides=track_overrides, backend=settings.backend, progress=progress, overwrite=True)),
        Step("landmarks", lambda: fresh([paths.landmarks_csv, paths.landmarks_info, paths.landmarks_trc, paths.movement], [paths.track_info]),
             landmarks),
        # After the landmarks, so that metrics.json carries their lost-landmark record.
        Step("evaluate", lambda: fresh([paths.metrics], [paths.track_info, paths.landmarks_info]), lambda: evaluate(run, backend=settings.backend)),
        Step("render trajectories", lambda: fresh([paths.trajectories_video, paths.trajectories_strip], [paths.track_info]), render_trajectories_step),
        Step("render landmarks", lambda: fresh([paths.landmarks_video], [paths.landmarks_csv]),
             lambda: render_landmarks(run, paths.renders, SYNTHETIC_HELDOUT[0], progress=progress)),
        Step("render novel view", lambda: fresh([paths.novel], [paths.track_info]), lambda: render_novel(renderer(), paths.renders)),
        Step("report", lambda: fresh([paths.report], [paths.metrics, paths.landmarks_info, paths.movement, paths.trajectories_video,
                                                      paths.trajectories_strip, paths.landmarks_video, paths.novel]),
             lambda: write_report(run, paths.report, backend=settings.backend)),
    ]
    times = run_steps("demo", steps, log, SettingsRecord.of(paths.out / SETTINGS_FILE, settings))
    iterations = json.loads(paths.track_info.read_text())["summary"].get("iterations_per_frame")
    return DemoResult(paths, method, iterations, json.loads(paths.metrics.read_text()), json.loads(paths.landmarks_info.read_text()), times)


def _number(value: float | None, unit: str, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f} {unit}"


def summary(result: DemoResult) -> str:
    """The closing text of ``mmcsplat demo``: every output path, the headline metrics, each step's time."""
    paths, metrics = result.paths, result.metrics
    accuracy = result.landmarks.get("accuracy_3d") or {}
    per_frame = [value for value in metrics.get("per_frame_val_masked_psnr") or [] if value is not None]
    tracked = f"{result.method}, {result.iterations} iterations per frame" if result.method == "iterative" else result.method
    rows: Sequence[tuple[str, Path]] = [
        ("capture (videos, calibration, ground truth)", paths.capture),
        ("session store", paths.session),
        ("first-frame fit", paths.run),
        (f"tracks ({tracked})", paths.tracks),
        ("metrics", paths.metrics),
        ("landmarks (the infant's joints, carried)", paths.landmarks_csv),
        ("landmarks for OpenSim / Pose2Sim", paths.landmarks_trc),
        ("movement measures, joint angles", paths.movement),
        ("tracking figure, video", paths.trajectories_video),
        ("tracking figure, strip of frames", paths.trajectories_strip),
        ("landmarks on the held-out camera", paths.landmarks_video),
        ("novel view", paths.novel),
        ("report", paths.report),
    ]
    width = max(len(label) for label, _ in rows)
    lines = [f"\nmmcsplat demo finished: its steps took {sum(step.seconds for step in result.steps):.0f} s"]
    lines += [f"  {label:<{width}}  {path}" for label, path in rows]
    heldout = ", ".join(metrics["heldout_cameras"])
    lines += [
        f"  held-out {heldout}: masked PSNR {_number(metrics['val_masked_psnr'], 'dB')} at the fitted frame, "
        f"mean {_number(sum(per_frame) / len(per_frame) if per_frame else None, 'dB')} over its {len(per_frame)} frames; "
        f"{metrics['num_gaussians']} Gaussians",
        f"  tracking error (3D): median {_number(metrics.get('tracking_median_mm'), 'mm')}, "
        f"90th percentile {_number(metrics.get('tracking_p90_mm'), 'mm')} "
        f"(median {_number(metrics.get('tracking_still_median_mm'), 'mm')} if nothing moved)",
        f"  {metrics['drift_summary']}",
        f"  {lost_line(result.landmarks['lost'])}",
        f"  landmarks (joints) where they moved > 1 cm: median error {_number(accuracy.get('moving_median_mm'), 'mm', 1)}, "
        f"against {_number(accuracy.get('still_moving_median_mm'), 'mm', 1)} if held still; over all frames {_number(accuracy.get('median_mm'), 'mm', 1)}",
        "  steps:",
    ]
    width = max(len(step.name) for step in result.steps)
    lines += [f"    {step.name:<{width}}  {step.seconds:7.1f} s{'  (already done)' if step.reused else ''}" for step in result.steps]
    return "\n".join(lines)
