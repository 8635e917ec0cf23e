"""``mmcsplat report``: one self-contained HTML page of a run or of a study.

A run (``run.json`` + ``checkpoint.pt``): the held-out camera's colour, depth and segmentation rendered
beside the ground truth the session holds, the metrics of ``mmcsplat evaluate`` (tracking too, and the
per-frame held-out PSNR as a chart), and the figures and videos ``mmcsplat render`` wrote into
``RUN/renders/``. A study (``results.json`` + ``results.md`` of ``mmcsplat compare``): its tables,
findings and charts. The page embeds every image and video (see :mod:`mmcsplat.outputs.report_html`).
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mmcsplat.configuration.registry import Registry
from mmcsplat.outputs.report_html import PAGE_START, command, esc, image, markdown_html, page, table, video
from mmcsplat.outputs.video import encode_png
from mmcsplat.plugin_api.errors import InputError, MissingFileError, OutputExistsError
from mmcsplat.storage.atomic import write_text_atomic
from mmcsplat.storage.completeness import require_finished
from mmcsplat.storage.curves import STAGES, read_curves
from mmcsplat.storage.run import CHECKPOINT, CURVES_FILE, METRICS_FILE, NOVEL_VIDEO, RENDERS_DIR, REPORT_FILE, RUN_INFO

if TYPE_CHECKING:  # torch-heavy modules are imported only when a run is reported
    from mmcsplat.outputs.renders import RunRenderer
    from mmcsplat.pipeline.run_frames import RunStates
    from mmcsplat.storage.session import SessionReader

STUDY_FILES = ("results.json", "results.md")
#: What ``mmcsplat render`` writes into RUN/renders/ (file pattern, caption, the option that makes it).
RENDER_OUTPUTS = (
    ("trajectories_*.png", "Tracking figure, a strip of five frames", "--trajectories"),
    ("trajectories_*.mp4", "Tracking figure", "--trajectories"),
    (NOVEL_VIDEO, "Novel view around the rig", "--novel"),
    ("depth_*.mp4", "Expected depth", "--depth"),
)
RUN_METRICS = (  # (metrics.json key, label)
    ("val_masked_psnr", "held-out masked PSNR (dB)"), ("val_interior_masked_psnr", "held-out masked PSNR, mask less its edge (dB)"),
    ("val_psnr", "held-out PSNR (dB)"), ("val_ssim", "held-out SSIM"), ("train_masked_psnr", "training masked PSNR (dB)"),
    ("train_interior_masked_psnr", "training masked PSNR, mask less its edge (dB)"), ("train_psnr", "training PSNR (dB)"),
    ("num_gaussians", "Gaussians"), ("floater_share", "opacity share outside the masks' hull (floaters)"),
    ("iterations", "iterations"), ("wall_s", "fit wall time (s)"), ("status", "status"),
)
TRACKING_METRICS = (
    ("tracking_method", "dynamics method"), ("tracking_median_mm", "3D error, median (mm)"),
    ("tracking_p90_mm", "3D error, 90th percentile (mm)"), ("tracking_still_median_mm", "median error if nothing moved (mm)"),
    ("tracking_2d_median_px", "2D error in the held-out camera, median (px)"),
    ("tracking_followed_points", "ground-truth points followed"), ("tracking_ground_truth_points", "ground-truth points"),
    ("drift", "drift detected"), ("drift_summary", "drift, explained"), ("drift_foreground", "foreground Gaussians (drift check)"),
)


def report_kind(path: Path) -> str:
    """``"run"`` or ``"study"``, from the directory's contents; errors name the path and what was expected."""
    path = Path(path)
    if not path.is_dir():
        raise MissingFileError(f"{path} is not a directory: report needs a run (`mmcsplat fit`) or a study output (`mmcsplat compare`)")
    if (path / RUN_INFO).is_file() and (path / CHECKPOINT).is_file():
        return "run"
    if all((path / name).is_file() for name in STUDY_FILES):
        return "study"
    folds = sorted(child.name for child in path.iterdir() if (child / RUN_INFO).is_file())
    if folds:
        raise InputError(f"{path} holds leave-one-camera-out folds ({', '.join(folds)}): report one of them, e.g. {path / folds[0]}")
    raise InputError(f"{path} is neither a run directory ({RUN_INFO} and {CHECKPOINT} of `mmcsplat fit`) "
                     f"nor a study output ({' and '.join(STUDY_FILES)} of `mmcsplat compare`)")


def write_report(path: Path, out: Path | None = None, backend: str | None = None, registry: Registry | None = None,
                 allow_incomplete: bool = False) -> Path:
    """Write the page of the run or study at ``path`` to ``out`` (default ``path``/report.html), atomically;
    returns where. ``backend`` renders a run's views (default: the renderer that fitted it). An unfinished run
    is refused, or with ``allow_incomplete`` reported under a banner saying what is unfinished."""
    path = Path(path)
    text = run_report(path, backend, registry, allow_incomplete) if report_kind(path) == "run" else study_report(path)
    target = Path(out) if out is not None else path / REPORT_FILE
    if target.is_file() and target.stat().st_size:
        with open(target, "rb") as handle:
            if handle.read(len(PAGE_START.encode())) != PAGE_START.encode():
                raise OutputExistsError(f"{target} exists and is not an mmcsplat report: report replaces only its own pages — move it or "
                                        "name another --out")
    target.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(target, text)
    return target


# ------------------------------------------------------------------------------------------------- run


def run_report(run: Path, backend: str | None = None, registry: Registry | None = None, allow_incomplete: bool = False) -> str:
    """The page of a run directory."""
    from mmcsplat.outputs.renders import RunRenderer
    from mmcsplat.pipeline.run_frames import RunStates

    states = RunStates(run)
    unfinished = require_finished(run, states.info, allow_incomplete)
    renderer = RunRenderer(states, backend=backend, registry=registry, progress=False)
    metrics = read_metrics(run)
    from mmcsplat.outputs.landmark_export import carried_unfinished
    from mmcsplat.outputs.report_landmarks import landmarks_section

    if not unfinished:  # a finished run whose metrics or landmarks were made before it was
        if metrics is not None and metrics.get("incomplete"):
            unfinished.append(f"its {METRICS_FILE} scored it before it was finished: run `mmcsplat evaluate {run}` again")
        unfinished += carried_unfinished(run)

    videos = [(path.read_bytes(), path.name) for path in sorted((Path(run) / RENDERS_DIR).glob("landmarks_*.mp4"))]
    sections = [run_summary(states), views_section(renderer, backend or states.info.renderer), metrics_section(run, metrics, states.first_frame),
                landmarks_section(run, videos), curves_section(run), plates_section(states.session), renders_section(run, states)]
    banner = [f'<p class="warning"><strong>Incomplete run</strong>: {esc("; ".join(unfinished))}</p>'] if unfinished else []
    return page(f"Run {Path(run).resolve()}", banner + sections)


def read_metrics(run: Path) -> dict[str, Any] | None:
    """``RUN/metrics.json`` of ``mmcsplat evaluate``, ``None`` when absent; an error naming it when garbled."""
    path = Path(run) / METRICS_FILE
    if not path.is_file():
        return None
    try:
        metrics = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise InputError(f"{path} is not readable JSON ({error}): run `mmcsplat evaluate {run}` again to rewrite it") from error
    if not isinstance(metrics, dict):
        raise InputError(f"{path}: expected a JSON object of metrics, got {type(metrics).__name__}: run `mmcsplat evaluate {run}` again")
    return metrics


def run_summary(states: RunStates) -> str:
    """What was fitted: session, configuration, renderer, cameras, frames, and how the session's frame numbers
    map to the capture's."""
    info = states.info
    tracked = f"{states.num_frames} frames from session frame {states.first_frame}" if states.tracks is not None else "no (first-frame fit only)"
    start, step = states.session.capture_start_step
    numbering = ("the capture's own" if (start, step) == (0, 1) else
                 f"session frame k is the capture's frame {start} + {step}·k" if step > 1 else f"session frame k is the capture's frame {start} + k")
    rows = [("session", info.session), ("configuration", info.config), ("renderer", info.renderer),
            ("fitted frame", info.frame), ("training cameras", ", ".join(info.train_cameras)),
            ("held-out cameras", ", ".join(info.heldout_cameras) or "none"), ("tracked", tracked),
            ("frame numbers", f"{numbering} (landmarks.csv and its exports number the capture's frames; the rest of this page the session's)")]
    return "<h2>Run</h2>" + table(None, rows)


def views_section(renderer: RunRenderer, backend: str) -> str:
    """The held-out cameras (else the first training camera) at the run's first frame: colour, depth and
    segmentation, rendered beside the session's ground truth."""
    states = renderer.states
    names = states.info.heldout_cameras or states.info.train_cameras[:1]
    role = "held-out" if states.info.heldout_cameras else "training (no camera is held out)"
    parts = [f"<h2>Renders beside the ground truth</h2><p>Session frame {states.first_frame}, {esc(role)} "
             f"camera{'s' if len(names) > 1 else ''}, rendered with {esc(backend)}.</p>"]
    parts += [camera_views(renderer, name) for name in names]
    return "\n".join(parts)


def camera_views(renderer: RunRenderer, name: str) -> str:
    """One camera's comparison table: rows colour, depth, segmentation; columns rendered, ground truth."""
    from mmcsplat.outputs.renders import colorize_depth, depth_range, to_uint8

    states = renderer.states
    camera = renderer.scaled(states.camera(name))
    render = renderer.render(0, camera)
    t = states.first_frame
    truth = states.session.frame(t, name) if states.session.present(name)[t] else None
    depth, alpha = render.depth[0].numpy(), render.alpha[0].numpy()
    try:
        near, far = depth_range(states, camera)
    except ValueError:  # the camera sees no Gaussian centre: range of what little is drawn, else a dummy
        drawn = depth[alpha > 0.5]
        near, far = (float(drawn.min()), float(drawn.max()) + 1e-3) if drawn.size else (0.0, 1.0)
    segmentation = render.features[0, ..., 0].clamp(0, 1).numpy()
    rows = [
        ("colour", to_uint8(render.rgb[0]), truth.rgb if truth is not None else None, "no frame in the session"),
        (f"depth ({near:.2f}–{far:.2f} m, turbo)", colorize_depth(depth, alpha, near, far),
         colorize_depth(truth.depth, truth.depth > 0, near, far) if truth is not None and truth.depth is not None else None,
         "the capture ships no depth"),
        ("segmentation", _gray(segmentation), _gray(truth.mask) if truth is not None and truth.mask is not None else None,
         "the session has no mask"),
    ]
    cells = []
    for label, rendered, actual, missing in rows:
        truth_cell = _frame_image(actual, f"{name} {label} ground truth") if actual is not None else f'<p class="note">{esc(missing)}</p>'
        cells.append(f"<tr><th>{esc(label)}</th><td>{_frame_image(rendered, f'{name} {label} rendered')}</td><td>{truth_cell}</td></tr>")
    return (f"<h3>{esc(name)}</h3><table><thead><tr><th></th><th>rendered</th><th>ground truth</th></tr></thead>"
            f"<tbody>{''.join(cells)}</tbody></table>")


def plates_section(session: SessionReader) -> str:
    """Every camera's clean plate, how it was made (recorded, or estimated from the sequence with its
    quality figures), or nothing when the session has none."""
    cells = []
    for name in session.camera_names:
        source = session.plate_source(name)
        if source is None:
            continue
        if source.get("kind") == "estimated":
            how = (f"estimated from {source.get('samples', '?')} frames{' (subject masked out)' if source.get('masked') else ''}: "
                   f"stable background {source.get('stable_share', 0):.0%}, never uncovered (inpainted) {source.get('uncovered_share', 0):.1%}")
        else:
            how = "recorded"
        cells.append(image(encode_png(np.ascontiguousarray(session.plate(name))), f"plate of {name}", f"{name}: {how}"))
    if not cells:
        return ""
    return ("<h2>Clean plates</h2><p>What each camera sees without the subject, the backdrop fits over plates are composited on. "
            "An estimated plate is the per-pixel median of frames spread over the recording; where the subject never moved off a "
            "pixel it is inpainted, and a low stable share means a moving background or a camera that moved.</p>" + "".join(cells))


def _gray(values: np.ndarray) -> np.ndarray:
    """[H, W] in [0, 1] (or bool) as a uint8 RGB image."""
    return np.repeat((np.asarray(values, dtype=np.float64) * 255).round().astype(np.uint8)[..., None], 3, axis=2)


def _frame_image(rgb: np.ndarray, alt: str) -> str:
    return image(encode_png(np.ascontiguousarray(rgb)), alt)


def metrics_section(run: Path, metrics: dict[str, Any] | None, first_frame: int = 0) -> str:
    """The metrics of ``mmcsplat evaluate``: overall, per camera, tracking, and the per-frame chart (its frames
    the session's, the run's first being ``first_frame``)."""
    if metrics is None:
        return f"<h2>Metrics</h2><p class=\"note\">No {METRICS_FILE} yet: {command('mmcsplat', 'evaluate', run)} scores the run.</p>"
    parts = ["<h2>Metrics</h2>", table(["metric", "value"], [(label, metrics[key]) for key, label in RUN_METRICS if key in metrics])]
    per_camera = metrics.get("per_camera", {})
    agreement = metrics.get("mask_agreement") or {}  # a camera's mask on the other masks' hull: low = bad calibration
    if per_camera:
        parts.append("<h3>Per camera</h3>" + table(
            ["camera", "split", "PSNR (dB)", "masked PSNR (dB)", "SSIM", "mask share on the others' hull"],
            [(name, s.get("split"), s.get("psnr"), s.get("masked_psnr"), s.get("ssim"), agreement.get(name)) for name, s in per_camera.items()]))
    if "tracking_method" in metrics:
        parts.append("<h3>Tracking</h3>" + table(["metric", "value"], [(label, metrics[key]) for key, label in TRACKING_METRICS if key in metrics]))
        if metrics.get("tracking_error"):
            parts.append(f'<p class="note">Tracking errors not measured: {esc(metrics["tracking_error"])}</p>')
        elif metrics.get("tracking_median_mm") is None:
            parts.append('<p class="note">No ground truth was found for the tracking errors (<code>mmcsplat evaluate --ground-truth</code>).</p>')
    if metrics.get("per_frame_val_masked_psnr"):
        parts.append(image(per_frame_chart(metrics, first_frame), "per-frame chart", "Held-out masked PSNR"
                           + (" and 3D tracking error" if metrics.get("tracking_per_frame_median_mm") else "") + " at every tracked frame"))
    return "\n".join(parts)


def per_frame_chart(metrics: dict[str, Any], first_frame: int = 0) -> bytes:
    """PNG: the held-out masked PSNR per tracked frame, and the median 3D tracking error when measured, over
    the session's frames from the run's ``first_frame``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    series = [("held-out masked PSNR (dB)", metrics["per_frame_val_masked_psnr"])]
    if metrics.get("tracking_per_frame_median_mm"):
        series.append(("3D error, median (mm)", metrics["tracking_per_frame_median_mm"]))
    figure_ = Figure(figsize=(6, 1.8 * len(series)), dpi=100)
    FigureCanvasAgg(figure_)
    all_axes = figure_.subplots(len(series), 1, sharex=True, squeeze=False)[:, 0]
    for index, ((label, values), axes) in enumerate(zip(series, all_axes, strict=True)):
        axes.plot(first_frame + np.arange(len(values)), [np.nan if v is None else v for v in values], marker=".", color=f"C{index}")
        axes.set_ylabel(label, fontsize=8)
        axes.grid(alpha=0.3)
    axes.set_xlabel("session frame")
    axes.xaxis.set_major_locator(MaxNLocator(integer=True))
    buffer = io.BytesIO()
    figure_.savefig(buffer, format="png", bbox_inches="tight")
    return buffer.getvalue()


def curves_section(run: Path) -> str:
    """The training curves of ``RUN/curves.csv``: loss and PSNR against iterations, one column per stage."""
    rows = read_curves(run)
    if not rows:
        return f'<h2>Training curves</h2><p class="note">No {CURVES_FILE}: the run was fitted by an mmcsplat that did not record curves.</p>'
    stages = [stage for stage in STAGES if any(row["stage"] == stage for row in rows)]
    caption = ("Loss and training-view PSNR as the training went: the first-frame fit (means over each round of the "
               "training cameras)" + (", then the tracking" if "track" in stages else "") + f"; the numbers are in {CURVES_FILE}")
    return "<h2>Training curves</h2>" + image(curves_chart(rows, stages), "training curves", caption)


def curves_chart(rows: list[dict], stages: list[str]) -> bytes:
    """PNG: loss (log scale) and PSNR against the stage's step, one column per stage."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure_ = Figure(figsize=(3.2 * len(stages) + 1, 3.6), dpi=100)
    FigureCanvasAgg(figure_)
    grid = figure_.subplots(2, len(stages), sharex="col", squeeze=False)
    for column, stage in enumerate(stages):
        mine = [row for row in rows if row["stage"] == stage]
        steps = [row["step"] for row in mine]
        loss_axes, psnr_axes = grid[:, column]
        loss_axes.plot(steps, [row["loss"] for row in mine], color="C0", marker="." if len(mine) < 60 else None)
        loss_axes.set_yscale("log")
        loss_axes.set_title({"fit": "first-frame fit", "track": "tracking"}[stage], fontsize=9)
        psnr_axes.plot(steps, [np.nan if row["psnr"] is None else row["psnr"] for row in mine], color="C1", marker="." if len(mine) < 60 else None)
        psnr_axes.set_xlabel("iteration", fontsize=8)
        for axes, label in ((loss_axes, "loss"), (psnr_axes, "PSNR (dB)")):
            axes.grid(alpha=0.3)
            if column == 0:
                axes.set_ylabel(label, fontsize=8)
    buffer = io.BytesIO()
    figure_.savefig(buffer, format="png", bbox_inches="tight")
    return buffer.getvalue()


def renders_section(run: Path, states: RunStates) -> str:
    """What ``mmcsplat render`` wrote into RUN/renders/, embedded; the command for what is missing."""
    folder = Path(run) / RENDERS_DIR
    parts = ["<h2>Figures and videos</h2>"]
    if states.tracks is None:
        parts.append(f'<p class="note">The run is not tracked: {command("mmcsplat", "track", run)} follows it through the '
                     "sequence; its renders then show the motion.</p>")
    missing: list[str] = []
    for pattern, caption, option in RENDER_OUTPUTS:
        files = sorted(folder.glob(pattern)) if folder.is_dir() else []
        for path in files:
            payload = path.read_bytes()
            parts.append(image(payload, path.name, f"{caption}: {path.name}") if path.suffix == ".png"
                         else video(payload, path.name, f"{caption}: {path.name}"))
        if not files and option not in missing:
            missing.append(option)
    if missing:
        parts.append(f'<p class="note">Not rendered yet: {command("mmcsplat", "render", run, *missing)} writes them into '
                     f"{esc(folder)}.</p>")
    return "\n".join(parts)


# ----------------------------------------------------------------------------------------------- study


def study_report(folder: Path) -> str:
    """The page of a study output: results.md (tables, findings, failed cells) with its charts embedded."""
    folder = Path(folder)
    results = json.loads((folder / "results.json").read_text())
    text = (folder / "results.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    if lines and lines[0].startswith("# "):  # the page has its own title
        text = "\n".join(lines[1:])

    def embed(relative: str, title: str) -> str:
        path = (folder / relative).resolve()
        if folder.resolve() not in path.parents or not path.is_file() or path.suffix != ".png":
            return f'<p class="note">Chart {esc(relative)} ({esc(title)}) is not a PNG file in the study folder.</p>'
        return image(path.read_bytes(), title, title)

    source = f"<p class=\"note\">Study file: {esc(results.get('source') or '—')}; output folder {esc(folder.resolve())}.</p>"
    return page(f"Study {results.get('study', folder.name)}", [source, markdown_html(text, embed)])
