"""``mmcsplat demo``: the main job on the built-in synthetic infant capture, end to end, in one folder.

Synthesize the capture, ingest and segment it, fit the first frame, track the sequence, evaluate on the
held-out camera (tracking errors against the capture's ground truth), carry the infant's joints through
the tracks as landmarks (scored against the true joints; exported as CSV and TRC), render the tracking
figure, the landmark overlay and a novel-view path, and write the HTML report — each step with the
functions its own command calls.

A rerun resumes: a step is skipped when its outputs exist and are newer than what they are made from.
Every output appears atomically, so a half-done step never reads as done. ``OUT/demo.json`` records
the settings; a rerun with other settings is refused rather than mixing two demos in one folder.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.configuration.config import Config, load_config
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.studies.spec import SYNTHETIC_HELDOUT, SYNTHETIC_SEGMENTER

#: Iterations per frame of the ``iterative`` method when the configuration has no [dynamics] table. One
#: iteration of the default demo (256×192, the 8 400 Gaussians of its first-frame fit) measured 0.09 CPU
#: seconds on one thread, so its 29 tracked frames take about 29 × 150 × 0.09 s ≈ 6.5 minutes.
TRACK_ITERATIONS = 150
SETTINGS_FILE = "demo.json"


@attrs.frozen
class DemoSettings:
    """What the demo makes: ``frames`` frames of ``width`` × ``height`` from the synthetic capture's
    cameras, fitted with configuration ``config`` after ``overrides`` on renderer ``backend`` (default:
    the configuration's), tracked with ``track_iterations`` iterations per frame of ``iterative``
    (default: the configuration's [dynamics] table, else :data:`TRACK_ITERATIONS`)."""

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
        from mmcsplat.outputs.report import RENDERS_DIR, REPORT_FILE
        from mmcsplat.pipeline.evaluate import METRICS_FILE
        from mmcsplat.pipeline.landmarks import LANDMARKS_CSV, LANDMARKS_INFO, MOVEMENT_JSON
        from mmcsplat.pipeline.track import TRACK_INFO
        from mmcsplat.storage.tracks import TRACKS_DIR

        run = out / "first-frame"
        renders = run / RENDERS_DIR
        trajectories = renders / f"trajectories_{SYNTHETIC_HELDOUT[0]}"
        return cls(out, out / "capture", out / "session.zarr", run, run / TRACKS_DIR, run / TRACK_INFO, run / METRICS_FILE,
                   run / LANDMARKS_CSV, run / LANDMARKS_INFO, run / "landmarks.trc", run / MOVEMENT_JSON, renders, trajectories.with_suffix(".mp4"),
                   trajectories.with_suffix(".png"), renders / f"landmarks_{SYNTHETIC_HELDOUT[0]}.mp4", renders / "novel.mp4",
                   run / REPORT_FILE)


@attrs.frozen
class StepTime:
    """One step's wall time; ``reused`` when its outputs were already there."""

    name: str
    seconds: float
    reused: bool


@attrs.frozen
class DemoResult:
    """What a demo run left: its paths, the tracking method, the metrics and each step's time."""

    paths: DemoPaths
    method: str
    iterations: int | None
    metrics: dict[str, Any]
    landmarks: dict[str, Any]
    steps: tuple[StepTime, ...]


def run_step(job: str, name: str, done: bool, action: Callable[[], object], log: Callable[[str], None]) -> StepTime:
    """Run ``action`` unless the step is ``done``; log ``[job] name done (… s)`` and return its time."""
    began = time.perf_counter()
    if not done:
        action()
    timed = StepTime(name, time.perf_counter() - began, done)
    log(f"[{job}] {name} {'already done' if done else 'done'} ({timed.seconds:.1f} s)")
    return timed


def tracking_choice(config: Config, iterations: int | None) -> tuple[str, list[str]]:
    """(dynamics method, tracking overrides): the method the configuration's [dynamics] table names, else
    ``iterative``; for ``iterative``, ``iterations`` per frame when given, else the table's, else
    :data:`TRACK_ITERATIONS`."""
    table = config.get("dynamics") or {}
    method = table.get("name") or "iterative"
    if method != "iterative":
        if iterations is not None:
            raise InputError(f"{config.source}: --track-iterations sets the iterative method's iterations per frame, "
                             f"but its [dynamics] table chooses {method!r}: set dynamics.KEY values instead")
        return method, []
    return method, [f"dynamics.iterations={iterations if iterations is not None else table.get('iterations', TRACK_ITERATIONS)}"]


def fresh(outputs: Iterable[Path], inputs: Iterable[Path] = ()) -> bool:
    """Whether every output exists and none is older than any input (a step made from them is done)."""
    outputs = list(outputs)
    if not all(path.exists() for path in outputs):
        return False
    newest = max((path.stat().st_mtime_ns for path in inputs), default=0)
    return all(path.stat().st_mtime_ns >= newest for path in outputs)


def check_settings(paths: DemoPaths, settings: DemoSettings) -> None:
    """Record ``settings`` in OUT/demo.json, or refuse when OUT was made with other settings."""
    record = paths.out / SETTINGS_FILE
    wanted = json.loads(json.dumps(attrs.asdict(settings)))  # as JSON reads it back
    if record.exists():
        made = json.loads(record.read_text())
        changed = sorted(key for key in wanted.keys() | made.keys() if made.get(key) != wanted.get(key))
        if changed:
            raise InputError(f"{paths.out} was made with other settings ({record}: "
                             + ", ".join(f"{key} {made.get(key)!r}, now {wanted.get(key)!r}" for key in changed)
                             + "): use another --out or delete it")
        return
    write_json_atomic(record, wanted)


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
    from mmcsplat.storage.run_info import RUN_INFO
    from mmcsplat.storage.session import SessionReader
    from mmcsplat.synthetic.synthesize import SynthConfig, synthesize

    if settings.frames < 2:
        raise InputError(f"the demo tracks the frames after the first: it needs at least 2 frames, not {settings.frames}")
    paths = DemoPaths.under(Path(out).resolve())  # absolute: the session records its capture, the run its session
    config = load_config(settings.config, settings.overrides)  # fail early on a bad configuration
    synth = SynthConfig(frames=settings.frames, width=settings.width, height=settings.height)
    method, track_overrides = tracking_choice(config, settings.track_iterations)
    paths.out.mkdir(parents=True, exist_ok=True)
    check_settings(paths, settings)
    run, fitted = paths.run, paths.run / RUN_INFO
    steps: list[StepTime] = []

    def step(name: str, done: bool, action: Callable[[], object]) -> None:
        steps.append(run_step("demo", name, done, action, log))

    def ingest_and_segment() -> None:
        # Both into a hidden sibling renamed into place: an interrupted segmentation is not a session.
        partial = paths.session.with_name(f".{paths.session.name}.partial")
        ingest(paths.capture, partial, holdout=list(SYNTHETIC_HELDOUT), overwrite=True, progress=progress)
        # The synthetic capture ships subject masks; segmenting keeps their central component per view.
        segment_session(partial, SYNTHETIC_SEGMENTER, progress=progress)
        os.replace(partial, paths.session)

    def renderer() -> RunRenderer:
        return RunRenderer(RunStates(run), backend=settings.backend, progress=progress)

    step("synthesize", (paths.capture / "calibration.toml").exists(), lambda: synthesize(paths.capture, synth, progress=progress))
    step("ingest + segment", paths.session.exists(), ingest_and_segment)
    step("first-frame fit", fitted.exists() and json.loads(fitted.read_text())["status"] == "complete",
         lambda: FirstFrameFit(SessionReader(paths.session), config, run, backend=settings.backend, progress=progress).run())
    step(f"track ({method})", fresh([paths.tracks, paths.track_info], [fitted]),
         lambda: track_run(run, dynamics=method, overrides=track_overrides, backend=settings.backend, progress=progress, overwrite=True))
    step("evaluate", fresh([paths.metrics], [paths.track_info]), lambda: evaluate(run, backend=settings.backend))

    def landmarks() -> None:
        track_landmarks(run, "synthetic")
        export_landmarks(run, trc=paths.landmarks_trc)

    step("landmarks", fresh([paths.landmarks_csv, paths.landmarks_info, paths.landmarks_trc, paths.movement], [paths.track_info]), landmarks)
    paths.renders.mkdir(exist_ok=True)
    step("render trajectories", fresh([paths.trajectories_video, paths.trajectories_strip], [paths.track_info]),
         lambda: render_trajectories(renderer(), paths.renders, SYNTHETIC_HELDOUT[0]))
    step("render landmarks", fresh([paths.landmarks_video], [paths.landmarks_csv]),
         lambda: render_landmarks(run, paths.renders, SYNTHETIC_HELDOUT[0], progress=progress))
    step("render novel view", fresh([paths.novel], [paths.track_info]), lambda: render_novel(renderer(), paths.renders))
    step("report", fresh([paths.report], [paths.metrics, paths.landmarks_info, paths.movement, paths.trajectories_video, paths.trajectories_strip,
                                          paths.landmarks_video, paths.novel]),
         lambda: write_report(run, paths.report, backend=settings.backend))
    iterations = json.loads(paths.track_info.read_text())["params"].get("iterations")
    return DemoResult(paths, method, iterations, json.loads(paths.metrics.read_text()), json.loads(paths.landmarks_info.read_text()),
                      tuple(steps))


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
        f"(median {_number(metrics.get('tracking_still_median_mm'), 'mm')} if nothing moved); drift: {'yes' if metrics.get('drift') else 'no'}",
        f"  landmarks (joints) where they moved > 1 cm: median error {_number(accuracy.get('moving_median_mm'), 'mm', 1)}, "
        f"against {_number(accuracy.get('still_moving_median_mm'), 'mm', 1)} if held still; over all frames {_number(accuracy.get('median_mm'), 'mm', 1)}",
        "  steps:",
    ]
    width = max(len(step.name) for step in result.steps)
    lines += [f"    {step.name:<{width}}  {step.seconds:7.1f} s{'  (already done)' if step.reused else ''}" for step in result.steps]
    return "\n".join(lines)
