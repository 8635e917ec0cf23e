"""``mmcsplat run CAPTURE --out DIR``: a user's own capture end to end, with defaults that work on a real
rig (docs/real-data.md): ingest → masks → plates → masks refined against them → first-frame fit → optical
flow → flow-guided track → landmarks → evaluate → renders → report.

- Masks: the capture's own when it brings them for every training camera (Dynamic3DGaussians ``seg/``,
  a ``masks/`` folder per camera, RGBA alpha: whatever its reader ingests); else, with 2D keypoints
  (``--keypoints PATH``, default the capture's ``pose_2d/``, else Pose2Sim's ``pose-associated/``, ``pose-sync/``
  or ``pose/``, else anipose's ``pose-2d-filtered/`` or ``pose-2d/``, else a FreeMoCap or Caliscope recording's 2D file (:func:`keypoint_folder`):
  a folder of OpenPose camera folders, of SLEAP or of DeepLabCut files, or one such file, or FreeMoCap's or Caliscope's; see :func:`keypoint_source`; their source's parameters
  ``--keypoints-set``, its ``camera_map`` and ``trial`` the reader's unless given: :func:`keypoints_with`) the skeleton-then-plate
  path of the ``keypoints`` segmenter; without, against the capture's recorded plates (``background``, method
  ``plate``) or, with nothing but videos and a calibration, the ``parallax`` segmenter (what the cameras
  agree stands off the floor: a still trunk too), refined against plates estimated with its masks held
  out. A segmenter named by the user (``--segmenter NAME``, its parameters ``--segmenter-set``: a
  person-segmentation model through ``onnx-semantic``, or a third party's plugin) makes every camera's masks
  instead, and plates are estimated around them. Which masks were used is printed and recorded in
  ``DIR/masks.json``. A capture ingested with recorded plates keeps them.
- Fit: ``visual-hull-plate`` with the start cube sized from the masks' visual hull (its reach from the
  rig centre plus 10 cm, never below the configuration's), so an adult or a mouse fits like an infant.
- Track: ``iterative`` at :data:`~mmcsplat.training.frame_steps.STEPS_PER_SECOND` steps a second of video
  (:func:`~mmcsplat.training.frame_steps.steps_per_frame`: 50 a frame at 60 fps, 100 at 30) and :data:`TRACK_MEANS_LR`, each frame started from the optical flow's lifted motion
  times :data:`TRACK_FLOW_GAIN`, and with a human's joints the body's parts held at their lengths
  (:data:`TRACK_LAMBDA_PARTS`). Keypoint guidance (``--track-keypoints WEIGHT``) pulls the tracks towards the
  training cameras' keypoints; it is off by default, since infants are where detectors fail. The fit's
  configuration carries these settings as its ``[dynamics]`` table, so RUN/run.json holds them and
  ``mmcsplat track DIR/run`` re-tracks as ``run`` did. A configuration whose ``[dynamics]`` table names another
  method (``deformation``, a third party's) is tracked with it as configured, none of these settings applied.
- Landmarks: a TRC of joints (``--joints FILE``, default the single ``CAPTURE/*.trc``, else ``CAPTURE/pose-3d/*.trc``), else a synthetic
  capture's true joints (its ``ground_truth.zarr``), else the 2D keypoints' own triangulation (what a capture
  with detections and no 3D joints has), bound at the fitted frame, scored against their later frames and
  against the keypoints in every camera. The same joints at the fitted frame give the body's parts, where
  they name its shoulders and hips there.

Every step writes atomically and is skipped on a rerun when its outputs are newer than its inputs, as in
the demo; ``DIR/run.json`` is not this file — the settings are recorded in ``DIR/capture.json`` once a
step has succeeded, and a rerun with other settings is then refused (a first run that fails before any
step is done leaves DIR free for corrected settings).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.pipeline.capture_session import (
    DEFAULT_SCALE,
    KEYPOINT_FOLDERS_NAMED,
    joints_source,
    keypoint_folder,
    keypoint_source,
    keypoints_with,
    missing_torso,
    prepare_capture_session,
    start_with_joints,
)
from mmcsplat.pipeline.image_scale import AUTO_SCALE, resolve_scale
from mmcsplat.pipeline.ingest import units_chosen, units_read
from mmcsplat.pipeline.steps import BEFORE_FIELD, SettingsRecord, Step, StepTime, fit_complete, fresh, made_in_place, run_steps
from mmcsplat.plugin_api.errors import InputError, SubjectMaskError
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.calibration import AUTO_UNITS, format_units
from mmcsplat.storage.run import LANDMARKS_CSV, LANDMARKS_INFO, METRICS_FILE, MOVEMENT_JSON, RENDERS_DIR, REPORT_FILE, RUN_INFO, TRACK_INFO, TRACKS_DIR
from mmcsplat.training.frame_steps import AUTO_STEPS, FEWEST_STEPS, STEPS_PER_SECOND, steps_per_frame

SETTINGS_FILE = "capture.json"
#: Which masks the run used (see :func:`mmcsplat.pipeline.capture_session.mask_choice`), written with the session.
MASKS_FILE = "masks.json"
DEFAULT_CONFIG = "visual-hull-plate"
#: Learning rate of the means while tracking, times the scene scale: ten times the fit's. Adam moves a mean
#: by about its rate a step, so at the fit's rate a frame's few dozen steps cannot reach a limb that moved
#: several centimetres since the flow's prediction (docs/results.md, "On a real capture").
TRACK_MEANS_LR = 1.6e-3
#: Weight of the iterative method's length prior within body parts, whose parts come from the joints' first
#: frame: without it a uniform limb shortens as it is tracked (docs/results.md, "Holding the body's parts"); 1
#: rather than 2 since two fits of the Pose2Sim demo, re-tracked, both came closer (the same section).
TRACK_LAMBDA_PARTS = 1.0
#: The lifted flow's displacement is doubled in each frame's prediction: at the Pose2Sim demo's true joints DIS
#: reports 0.73 of their motion, and a fit that starts short does not close the gap, so the tracks lag and the lag
#: adds up (docs/results.md, "The flow's shortfall").
TRACK_FLOW_GAIN = 2.0


@attrs.frozen
class CaptureSettings:
    """What ``mmcsplat run`` does with a capture; ``None`` paths are looked for in the capture folder."""

    calibration: str | None = None
    units: str = AUTO_UNITS
    scale: float | str = DEFAULT_SCALE
    frames: tuple[int | None, int | None, int | None] = (None, None, None)
    cameras: tuple[str, ...] = attrs.field(default=(), converter=tuple)
    holdout: tuple[str, ...] = attrs.field(default=(), converter=tuple)
    keypoints: str | None = None
    #: Parameters of the keypoints' source (``--keypoints-set``), e.g. its ``camera_map``.
    keypoint_options: tuple[str, ...] = attrs.field(default=(), converter=tuple, metadata={BEFORE_FIELD: ()})
    joints: str | None = None
    config: str = DEFAULT_CONFIG
    overrides: tuple[str, ...] = attrs.field(default=(), converter=tuple)
    reader_options: tuple[str, ...] = attrs.field(default=(), converter=tuple, metadata={BEFORE_FIELD: ()})
    #: Steps a frame of the iterative method, or ``auto`` (:func:`~mmcsplat.training.frame_steps.steps_per_frame`).
    track_iterations: int | str = AUTO_STEPS
    track_means_lr: float = TRACK_MEANS_LR
    track_lambda_parts: float = TRACK_LAMBDA_PARTS
    track_flow_gain: float = attrs.field(default=TRACK_FLOW_GAIN, metadata={BEFORE_FIELD: 1.0})
    track_keypoints: float = attrs.field(default=0.0, metadata={BEFORE_FIELD: 0.0})
    #: The renderer backend to fit with, instead of the configuration's; the later steps render with the fit's.
    backend: str | None = attrs.field(default=None, metadata={BEFORE_FIELD: None})
    #: A segmenter plugin that makes the masks instead of the keypoints, the plates or the subject's motion.
    segmenter: str | None = attrs.field(default=None, metadata={BEFORE_FIELD: None})
    segmenter_options: tuple[str, ...] = attrs.field(default=(), converter=tuple, metadata={BEFORE_FIELD: ()})


def toml_literal(value: Any) -> str:
    """``value`` (a string, number, boolean, list or table of them) as a TOML literal: strings as JSON writes
    them (a JSON string is a TOML basic string), tables inline."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(str(key))} = {toml_literal(item)}" for key, item in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_literal(item) for item in value) + "]"
    return json.dumps(value)


def quoted_override(key: str, value: Any) -> str:
    """``KEY=VALUE`` for ``--set``, the value written as a TOML literal (:func:`toml_literal`), so that a path with
    quotes, backslashes or spaces, or a keypoint source's ``camera_map`` table, arrives as it is."""
    return f"{key}={toml_literal(value)}"


def frames_with_joints(settings: CaptureSettings, trc: Path, log: Callable[[str], None]) -> CaptureSettings:
    """``settings`` whose frames start where the joints of ``trc`` do
    (:func:`~mmcsplat.pipeline.capture_session.start_with_joints`): without ``--frames`` the run starts there, said."""
    start, stop, step = settings.frames
    until = stop if stop is not None else ""
    first = start_with_joints(trc, start, f"--frames {start}:{until}", lambda first: f"give --frames {first}:{until}")
    if first is None:
        return settings
    log(f"run: frames from {first} on, where the joints of {trc} start (its OrigDataStartFrame)")
    return attrs.evolve(settings, frames=(first, stop, step))


def guidance_overrides(weight: float, source: dict[str, Any] | None, capture: Path) -> list[str]:
    """The tracking overrides that turn keypoint guidance on at ``weight`` from the keypoints ``source`` reads
    (:func:`~mmcsplat.pipeline.capture_session.keypoint_source`); an error when the capture has none."""
    if source is None:
        raise InputError(f"--track-keypoints: {capture} has no 2D keypoints to guide the tracking with (none of "
                         f"{KEYPOINT_FOLDERS_NAMED}): give --keypoints PATH, or leave --track-keypoints at 0")
    return [f"dynamics.lambda_keypoints={weight}", *(quoted_override(f"dynamics.keypoints.{key}", value) for key, value in source.items())]


@attrs.frozen
class CaptureResult:
    """What a run left: its folder, the metrics, the landmarks' record (empty without joints) and each step's time."""

    out: Path
    run: Path
    metrics: dict[str, Any]
    landmarks: dict[str, Any]
    steps: tuple[StepTime, ...]


def run_capture(capture: str | Path, out: str | Path, settings: CaptureSettings = CaptureSettings(), progress: bool = True,
                log: Callable[[str], None] = print) -> CaptureResult:
    """Run every step into ``out`` (module docstring); ``log`` gets one line per step."""
    from mmcsplat.configuration.config import PluginChoice, apply_overrides, load_config
    from mmcsplat.configuration.registry import default_registry
    from mmcsplat.outputs.landmark_video import render_landmarks
    from mmcsplat.outputs.renders import RunRenderer, render_trajectories
    from mmcsplat.outputs.report import write_report
    from mmcsplat.pipeline.evaluate import evaluate
    from mmcsplat.pipeline.fit import FirstFrameFit, renderer_choice
    from mmcsplat.pipeline.flow import compute_flow, flow_complete
    from mmcsplat.pipeline.ingest import capture_reader
    from mmcsplat.pipeline.landmarks import track_landmarks
    from mmcsplat.pipeline.run_frames import RunStates
    from mmcsplat.pipeline.segment import BuiltSegmenter
    from mmcsplat.pipeline.track import DEFAULT_DYNAMICS, dynamics_choice, track_run
    from mmcsplat.storage.session import SessionReader
    from mmcsplat.training.settings import FitSettings

    capture, out = Path(capture).resolve(), Path(out).resolve()
    if not capture.is_dir():
        raise InputError(f"capture {capture} is not a folder")
    # A bad reader or keypoint option fails before anything runs.
    reader_options = apply_overrides({}, settings.reader_options, "--reader-set")
    keypoints = keypoint_folder(capture, settings.keypoints)
    if settings.keypoint_options and not keypoints:
        raise InputError(f"--keypoints-set {' '.join(settings.keypoint_options)}: {capture} has no 2D keypoints (none of "
                         f"{KEYPOINT_FOLDERS_NAMED}) for it to set: give --keypoints PATH")
    source = keypoints_with(keypoint_source(keypoints), apply_overrides({}, settings.keypoint_options, "--keypoints-set"),
                            reader_options) if keypoints else None
    # The keypoint source's parameters: checked here, and the ones its landmarks step scores with.
    keypoint_params = {key: value for key, value in source.items() if key != "name"} if source else None
    if source:
        try:
            default_registry().create("landmarks", source["name"], **keypoint_params)
        except InputError as error:
            raise InputError(f"--keypoints-set: {error}") from error
        extra = {key: value for key, value in source.items() if key not in ("name", "folder", "files", "path")}
        log(f"run: keypoints: {source['name']} from {keypoints}" + (f" ({', '.join(f'{key}={value}' for key, value in extra.items())})"
                                                                  if extra else ""))
    # Without a TRC or a synthetic truth, the 2D keypoints' own triangulation: what a capture with detections only has.
    joints = joints_source(capture, settings.joints, reader_options.get("trial")) or source
    joint_params = {key: value for key, value in joints.items() if key != "name"} if joints else {}
    if joints is not None and joints is source:
        log("run: joints: the keypoints' own triangulation (the capture has no TRC): bound at the fitted frame, carried, and scored "
            "against it and the keypoints")
    if joints is not None and joints["name"] == "trc":
        settings = frames_with_joints(settings, Path(joints["path"]), log)
    # A configuration may name another dynamics method (a third party's): run tracks with it as configured.
    method = dynamics_choice(load_config(settings.config, settings.overrides)).name
    iterative = method == DEFAULT_DYNAMICS  # the tracker run's own settings are for
    if not iterative:
        if settings.track_keypoints:
            raise InputError(f"--track-keypoints guides the {DEFAULT_DYNAMICS} tracker; {settings.config} tracks with {method!r}: leave it at 0, "
                             f"or track with {DEFAULT_DYNAMICS}")
        log(f"run: tracking with {method!r}, as the configuration's [dynamics] table sets it (run's steps a frame, flow start and "
            f"body parts are the {DEFAULT_DYNAMICS} tracker's settings: not applied)")
    tracking = [f"dynamics.means_lr={settings.track_means_lr}", f"dynamics.flow_gain={settings.track_flow_gain}"]
    if settings.track_keypoints:  # a negative weight is refused by the dynamics' own check below
        tracking += guidance_overrides(settings.track_keypoints, source, capture)

    def tracked_with(iterations: int) -> list[str]:
        return [f"dynamics.name={DEFAULT_DYNAMICS}", f"dynamics.iterations={iterations}", *tracking] if iterative else []
    start, stop, step = settings.frames
    count = None if stop is None else len(range(start or 0, stop, step or 1))  # without STOP it depends on the capture's length
    if count is not None and count < 2:
        raise InputError(f"--frames {start if start is not None else ''}:{stop}{f':{step}' if step else ''} selects {count} frame(s): "
                         "run tracks a sequence, give two frames at least (three unless the capture records its plates)")
    training = [name for name in settings.cameras if name not in settings.holdout]
    if settings.cameras and len(training) < 2:
        raise InputError(f"--cameras {','.join(settings.cameras)} with --holdout {','.join(settings.holdout) or '(none)'} leaves "
                         f"{len(training)} camera(s) to train on ({','.join(training) or 'none'}): a fit needs two at least")
    # A bad segmenter, configuration or tracking value fails before anything runs.
    if settings.segmenter_options and not settings.segmenter:
        raise InputError(f"--segmenter-set {' '.join(settings.segmenter_options)} without --segmenter: name the segmenter it sets")
    segmenter = BuiltSegmenter.of(PluginChoice("segmenter", settings.segmenter, apply_overrides({}, settings.segmenter_options, "--segmenter-set"))) \
        if settings.segmenter else None
    # The fit's configuration names the tracking too, so RUN/run.json holds it and `mmcsplat track RUN` re-tracks as this run did.
    # `auto` iterations need the session's frame rate: checked here with the fewest they can come to (at any rate).
    try:
        provisional = steps_per_frame(settings.track_iterations, math.inf)
    except ValueError as error:
        raise InputError(f"track_iterations: {error}") from error
    fit_config = load_config(settings.config, [*settings.overrides, *tracked_with(provisional)])
    dynamics_choice(fit_config, method).build()
    renderer_choice(fit_config, settings.backend).build()  # one that cannot run here (no GPU, no gsplat): named before minutes of ingest
    if settings.track_keypoints:
        log(f"run: keypoint guidance from the training cameras' {source['name']} keypoints, weight {settings.track_keypoints:g}: their 2D "
            "errors are no longer a test of the tracks (a held-out camera's still is)")
    session, run = out / "session.zarr", out / "run"

    @functools.cache
    def session_steps() -> list[str]:
        """The tracking overrides with the iterations this session's frame rate gives (said once)."""
        if settings.track_iterations != AUTO_STEPS or not iterative:
            return tracked_with(provisional)
        fps = SessionReader(session).fps
        iterations = steps_per_frame(AUTO_STEPS, fps)
        log(f"run: tracking at {iterations} steps a frame ({STEPS_PER_SECOND:g} a second of video at {fps:g} fps, "
            f"{FEWEST_STEPS} at least)")
        return tracked_with(iterations)

    @functools.cache
    def session_tracking() -> list[str]:
        """The tracking overrides for this session: its steps a frame, and the body's parts where the joints
        name a torso at the fitted frame (said once when they do not)."""
        if joints is None or settings.track_lambda_parts == 0 or not iterative:
            return session_steps()
        frame = FitSettings.from_config(fit_config).frame
        missing = missing_torso(default_registry().create("landmarks", joints["name"], **joint_params), SessionReader(session), frame)
        if missing is not None:
            log(f"run: no body parts held: {missing}")
            return session_steps()
        return [*session_steps(), f"dynamics.lambda_parts={settings.track_lambda_parts}", f"dynamics.skeleton.name={joints['name']}",
                *(quoted_override(f"dynamics.skeleton.{key}", value) for key, value in joint_params.items())]

    if not session.exists():
        capture_reader(capture, reader_options=reader_options)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)

    def prepare(partial: Path) -> None:
        choice = prepare_capture_session(capture, partial, calibration=Path(settings.calibration) if settings.calibration else None,
                                         units=settings.units, frames=slice(*settings.frames), scale=settings.scale,
                                         cameras=list(settings.cameras) or None, holdout=list(settings.holdout), source=source,
                                         reader_options=reader_options, segmenter=segmenter, progress=progress)
        write_json_atomic(out / MASKS_FILE, choice)
        stored = SessionReader(partial)
        chosen = units_chosen(stored, settings.units)
        if chosen:
            calibration = stored.provenance.get("reader", {}).get("calibration")
            why = "its format's unit" if calibration and format_units(Path(calibration)) else "--units auto: in metres its rig would be implausible"
            log(f"run: calibration read in {chosen} ({why})")
        log(f"run: masks: {choice['detail']}")

    def fit() -> None:
        try:
            first = FirstFrameFit(SessionReader(session), load_config(settings.config, [*settings.overrides, *session_tracking()]), run,
                                  backend=settings.backend, progress=progress)
            for grown in first.grown_regions:
                log(f"run: {grown}")
            first.run()
        except SubjectMaskError as error:
            if json.loads((out / MASKS_FILE).read_text()).get("masks") != "parallax":
                raise
            frames = SessionReader(session).num_frames
            raise SubjectMaskError(f"{error} (the masks come from the subject's motion against plates estimated from these {frames} frames: where "
                                   "they are nearly empty it barely moved; give more frames, a plates/ folder of the empty scene, or 2D keypoints "
                                   f"in one of {KEYPOINT_FOLDERS_NAMED} or --keypoints)") from error

    def landmarks() -> None:
        track_landmarks(run, joints["name"], joint_params, keypoints=source["name"] if source else None,
                        keypoint_params=keypoint_params)

    renders = run / RENDERS_DIR

    def rendered(pattern: str) -> list[Path]:
        return list(renders.glob(pattern))

    steps = [
        # Into a hidden sibling renamed into place: a session half segmented is not a session.
        Step("ingest + masks + plates", session.exists, lambda: made_in_place(session, prepare)),
        Step("first-frame fit", lambda: fit_complete(run), fit),
        Step("optical flow", lambda: flow_complete(session), lambda: compute_flow(session, progress=progress)),
        Step(f"track ({method})", lambda: fresh([run / TRACKS_DIR, run / TRACK_INFO], [run / RUN_INFO]),
             lambda: track_run(run, dynamics=method, overrides=session_tracking(), progress=progress,
                               overwrite=True)),
    ]
    if joints is not None:
        steps += [
            Step("landmarks", lambda: fresh([run / LANDMARKS_CSV, run / LANDMARKS_INFO, run / MOVEMENT_JSON], [run / TRACK_INFO]), landmarks),
            Step("render landmarks", lambda: bool(rendered("landmarks_*.mp4")) and fresh(rendered("landmarks_*.mp4"), [run / LANDMARKS_CSV]),
                 lambda: render_landmarks(run, _made(renders), progress=progress)),
        ]
    # After the landmarks, so that metrics.json carries their lost-landmark record.
    scored = [run / TRACK_INFO, *([run / LANDMARKS_INFO] if joints is not None else [])]
    steps += [
        Step("evaluate", lambda: fresh([run / METRICS_FILE], scored), lambda: evaluate(run)),
        Step("render trajectories", lambda: bool(rendered("trajectories_*.png")) and fresh(rendered("trajectories_*.png"), [run / TRACK_INFO]),
             lambda: render_trajectories(RunRenderer(RunStates(run), progress=progress), _made(renders))),
        Step("report", lambda: fresh([run / REPORT_FILE], [run / METRICS_FILE]), lambda: write_report(run)),
    ]
    try:
        times = run_steps("run", steps, log, SettingsRecord.of(out / SETTINGS_FILE, settings, {"scale": lambda value: _scale_in(session, value),
                                                                                     "track_iterations": lambda value: _iterations_in(session, value),
                                                                                     "units": lambda value: _units_in(session, value)}))
    except BaseException:
        if created and not any(out.iterdir()):  # refused before any step made something: no empty folder left behind
            out.rmdir()
        raise
    info = json.loads((run / LANDMARKS_INFO).read_text()) if (run / LANDMARKS_INFO).exists() else {}
    return CaptureResult(out, run, json.loads((run / METRICS_FILE).read_text()), info, times)


def _scale_in(session: Path, scale: Any) -> Any:
    """The number ``scale`` stands for in the folder whose session is ``session``: ``auto`` resolved against
    the cameras that session was ingested from (its provenance), so a folder made with ``--scale 0.25``
    resumes under ``auto`` where that is what ``auto`` gives, and the other way round."""
    if scale == AUTO_SCALE and session.exists():
        from mmcsplat.storage.session import SessionReader

        cameras = SessionReader(session).recorded_cameras()
        if cameras:
            return resolve_scale(scale, list(cameras.values()))
    return scale


def _units_in(session: Path, units: Any) -> Any:
    """The units ``units`` stands for in the folder whose session is ``session``: ``auto`` as its reader
    resolved it (its provenance; metres for a reader that records none, as ``auto`` reads poses without a
    unit), so a folder made with ``--units mm`` resumes under ``auto`` where the rig reads in millimetres,
    and the other way round."""
    if units == AUTO_UNITS and session.exists():
        from mmcsplat.storage.session import SessionReader

        return units_read(SessionReader(session))
    return units


def _iterations_in(session: Path, value: Any) -> Any:
    """The steps a frame ``value`` stands for in the folder whose session is ``session``: ``auto`` resolved at
    that session's frame rate, so a folder tracked at 50 steps a frame resumes under ``auto`` where that is
    what ``auto`` gives."""
    if value == AUTO_STEPS and session.exists():
        from mmcsplat.storage.session import SessionReader

        return steps_per_frame(value, SessionReader(session).fps)
    return value


def _made(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def summary(result: CaptureResult) -> str:
    """The closing text of ``mmcsplat run``: outputs, headline figures, warnings, each step's time."""
    metrics = result.metrics
    lines = [f"\nmmcsplat run finished: its steps took {sum(step.seconds for step in result.steps):.0f} s",
             f"  run folder  {result.run}", f"  report      {result.run / REPORT_FILE}",
             f"  held-out {', '.join(metrics['heldout_cameras']) or '(none)'}: masked PSNR "
             f"{'n/a' if metrics.get('val_masked_psnr') is None else format(metrics['val_masked_psnr'], '.2f') + ' dB'}, "
             f"training views {'n/a' if metrics.get('train_masked_psnr') is None else format(metrics['train_masked_psnr'], '.2f') + ' dB'}; "
             f"{metrics['num_gaussians']} Gaussians"]
    accuracy = result.landmarks.get("accuracy_3d") or {}
    if accuracy.get("median_mm") is not None:
        floor = result.landmarks.get("reference_floor")
        lines.append(f"  joints: median 3D error {accuracy['median_mm']:.1f} mm against the {result.landmarks['described']} "
                     f"({accuracy['still_median_mm']:.1f} mm if held still"
                     + (f"; {floor['median_mm']:.1f} mm for a body of fixed bones placed nearest it, the reference's floor)" if floor else ")"))
    lines += [f"  warning: {warning}" for warning in metrics.get("warnings", [])]
    lines += [f"    {step.name:<24} {step.seconds:7.1f} s{'  (already done)' if step.reused else ''}" for step in result.steps]
    return "\n".join(lines)
