"""One cell of a study, run in a worker: the first-frame fit (resumed from its checkpoint), tracking when
the configuration has a ``[dynamics]`` table, the held-out evaluation, and the outcome record.

OUT/cells/KEY/ is the cell's run directory (``run.json``, ``checkpoint.pt``, ``tracks.zarr``,
``metrics.json``), plus ``cell.json`` (what the cell is, written when it starts) and ``result.json``
(how it ended, written last: a cell with one is done).

Cells that differ only in their ``[dynamics]`` table (a tracking ablation's rows) start from one fit: it is
made once in OUT/fits/FIT_KEY/ (:attr:`~mmcsplat.studies.spec.CellSpec.fit_key`), under a lock that a cell
of the same fit in another worker waits on, and copied into each cell, whose ``run.json`` then records the
cell's whole configuration. Their rows then differ by their tracking alone, and the fit's time is spent once.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import attrs

from mmcsplat.pipeline.steps import Step, fit_complete, run_steps
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.run import RUN_INFO, TRACK_INFO, TRACKS_DIR
from mmcsplat.storage.run_info import RunInfo
from mmcsplat.studies.spec import CellSpec

if TYPE_CHECKING:
    from mmcsplat.configuration.config import Config

CELL_FILE = "cell.json"
RESULT_FILE = "result.json"
COMPLETE, FAILED, DIVERGED = "complete", "failed", "diverged"


@attrs.frozen
class CellOutcome:
    """How a cell ended and what it measured (``None`` where a metric does not apply or the cell failed).

    ``wall_s`` and ``iterations_per_s`` are the first-frame fit's (time spent training, over resumes);
    ``track_*`` the dynamics step's (``track_prediction``: how each frame's start was predicted, as
    track.json's summary records it — ``flow`` or ``constant-velocity`` — for a method that says); ``per_frame_val_masked_psnr`` and ``tracking_per_frame_median_mm``
    are per tracked frame; ``resumed_at`` the fit iteration a restarted cell went on from.
    ``status`` is ``diverged`` for a fit stopped by a NaN/Inf (its message in ``error``), ``failed`` for
    any other error. ``floater_share`` is evaluate's share of opacity mass outside the masks' visual
    hull, ``mask_agreement`` its per-camera agreement of each mask with the other cameras' hull,
    ``drift`` its drift verdict (tracked cells), ``loss_min``/``loss_final`` and ``warnings`` the fit's
    (run.json). ``landmark_*`` are the carried joints' errors against the capture's own; ``joint_angle_*`` their
    knee, elbow, hip and shoulder flexion's error, and ``*_flexion_range_deg`` each joint's range of motion
    (the mean of the two sides') from the cell's movement.json — None in a cell recorded before they existed.
    """

    key: str
    status: str
    error: str | None = None
    val_masked_psnr: float | None = None
    val_psnr: float | None = None
    val_ssim: float | None = None
    train_masked_psnr: float | None = None
    val_interior_masked_psnr: float | None = None
    train_psnr: float | None = None
    num_gaussians: int | None = None
    floater_share: float | None = None
    mask_agreement: dict[str, float] | None = None
    drift: bool | None = None
    loss_min: float | None = None
    loss_final: float | None = None
    warnings: list[str] | None = None
    iterations: int | None = None
    wall_s: float | None = None
    iterations_per_s: float | None = None
    track_method: str | None = None
    track_wall_s: float | None = None
    track_wall_s_per_frame: float | None = None
    track_prediction: str | None = None
    tracking_median_mm: float | None = None
    tracking_p90_mm: float | None = None
    landmark_median_mm: float | None = None
    landmark_moving_median_mm: float | None = None
    landmark_still_moving_median_mm: float | None = None
    joint_angle_median_error_deg: float | None = None
    joint_angle_p90_error_deg: float | None = None
    knee_flexion_range_deg: float | None = None
    elbow_flexion_range_deg: float | None = None
    hip_flexion_range_deg: float | None = None
    shoulder_flexion_range_deg: float | None = None
    per_frame_val_masked_psnr: list[float | None] | None = None
    tracking_per_frame_median_mm: list[float] | None = None
    resumed_at: int | None = None
    cell_wall_s: float | None = None

    @classmethod
    def read(cls, cell_dir: Path) -> CellOutcome | None:
        """The recorded outcome of a done cell, ``None`` for one never finished."""
        path = Path(cell_dir) / RESULT_FILE
        if not path.exists():
            return None
        record = json.loads(path.read_text())
        known = {field.name for field in attrs.fields(cls)}
        return cls(**{key: value for key, value in record.items() if key in known})


def run_cell(spec: CellSpec, cell_dir: str | Path, fits_dir: str | Path | None = None) -> CellOutcome:
    """Run (or finish) one cell in ``cell_dir``, a tracked cell from the shared fit in ``fits_dir`` when
    given (module docstring); an error inside the cell is its outcome, not an exception, so one failing
    cell never stops a study. Interruptions propagate."""
    import traceback

    from mmcsplat.training.finite import NonFiniteError

    cell_dir = Path(cell_dir)
    cell_dir.mkdir(parents=True, exist_ok=True)
    (cell_dir / RESULT_FILE).unlink(missing_ok=True)  # a retried cell is not done until it ends again
    shared = Path(fits_dir) / spec.fit_key if fits_dir is not None and spec.has_dynamics else None
    write_json_atomic(cell_dir / CELL_FILE, attrs.asdict(spec) | {"key": spec.key, "fit": str(shared) if shared else None})
    began = time.perf_counter()
    try:
        fields = _run(spec, cell_dir, shared)
        outcome = CellOutcome(spec.key, COMPLETE, **fields, cell_wall_s=round(time.perf_counter() - began, 3))
    except Exception as error:  # the study reports it; the traceback goes to the cell's own record
        (cell_dir / "error.txt").write_text(traceback.format_exc())
        status = DIVERGED if isinstance(error, NonFiniteError) else FAILED
        outcome = CellOutcome(spec.key, status, f"{type(error).__name__}: {error}", cell_wall_s=round(time.perf_counter() - began, 3))
    write_json_atomic(cell_dir / RESULT_FILE, attrs.asdict(outcome))
    return outcome


def _run(spec: CellSpec, cell_dir: Path, shared: Path | None) -> dict[str, Any]:
    """The cell's steps — its first-frame fit (resumed from its checkpoint; in ``shared`` and copied, when
    given) unless complete, its tracking unless done (a ``tracks.zarr`` without its ``track.json`` was cut
    short between the two and is replaced) — then its evaluation and landmarks, and the fields of its
    outcome."""
    from mmcsplat.pipeline.evaluate import evaluate_run
    from mmcsplat.pipeline.fit import FirstFrameFit
    from mmcsplat.pipeline.track import track_run
    from mmcsplat.storage.session import SessionReader

    resumed_at: int | None = None  # the iteration a fit run by this call went on from

    def fit(run: Path, config: Config) -> None:
        nonlocal resumed_at
        resumed_at = FirstFrameFit(SessionReader(spec.session_url), config, run, holdout=spec.holdout, progress=False).run().resumed_from

    def shared_fit() -> None:
        import filelock

        shared.parent.mkdir(parents=True, exist_ok=True)
        with filelock.FileLock(shared.with_name(f"{shared.name}.lock")):  # a cell of the same fit elsewhere waits here
            if not fit_complete(shared):
                fit(shared, spec.fit_config)
        _copy_fit(shared, cell_dir, spec)

    steps = [Step("first-frame fit", lambda: fit_complete(cell_dir),
                  shared_fit if shared is not None else lambda: fit(cell_dir, spec.config))]
    if spec.has_dynamics:
        steps.append(Step("track", (cell_dir / TRACK_INFO).exists,
                          lambda: track_run(cell_dir, progress=False, overwrite=(cell_dir / TRACKS_DIR).exists())))
    run_steps("cell", steps)
    info = RunInfo.read(cell_dir)
    track = json.loads((cell_dir / TRACK_INFO).read_text()) if spec.has_dynamics else {}
    metrics = evaluate_run(cell_dir, ground_truth=Path(spec.ground_truth) if spec.ground_truth else None)
    landmarks = _landmarks(spec, cell_dir) if spec.has_dynamics else {}
    wall = info.wall_s
    return {
        **{key: metrics.get(key) for key in ("val_masked_psnr", "val_psnr", "val_ssim", "train_masked_psnr", "val_interior_masked_psnr", "train_psnr",
                                             "num_gaussians", "floater_share", "mask_agreement", "drift", "tracking_median_mm", "tracking_p90_mm",
                                             "per_frame_val_masked_psnr", "tracking_per_frame_median_mm")},
        "loss_min": info.loss_min,
        "loss_final": info.loss_final,
        "warnings": list(info.warnings),
        "iterations": info.iterations,
        "wall_s": wall,
        "iterations_per_s": info.iterations / wall if wall > 0 else None,
        "track_method": track.get("method"),
        "track_wall_s": track.get("wall_s"),
        "track_wall_s_per_frame": track.get("wall_s_per_frame"),
        "track_prediction": track.get("summary", {}).get("prediction"),
        "resumed_at": resumed_at,
        **landmarks,
    }


def _copy_fit(shared: Path, cell_dir: Path, spec: CellSpec) -> None:
    """The shared fit's files copied into ``cell_dir``, run.json last (it marks the fit complete) and with
    the cell's whole configuration, whose ``[dynamics]`` table tracking reads."""
    for entry in shared.iterdir():
        if entry.name == RUN_INFO:
            continue
        if entry.is_dir():
            shutil.copytree(entry, cell_dir / entry.name, dirs_exist_ok=True)
        else:
            shutil.copyfile(entry, cell_dir / entry.name)
    info = RunInfo.read(shared)
    attrs.evolve(info, config_values=dict(spec.config_values)).write(cell_dir)


#: The joint angles whose range of motion a cell reports (keys of :data:`mmcsplat.analysis.movement.JOINT_ANGLES`).
HEADLINE_ANGLES = ("knee_flexion", "elbow_flexion", "hip_flexion", "shoulder_flexion")


def _landmarks(spec: CellSpec, cell_dir: Path) -> dict[str, float | None]:
    """The error of the session's joints carried by the cell's tracks — a capture's TRC (``spec.joints``), else
    the synthetic capture's — and of their joint angles, and each headline angle's range of motion
    (docs/landmarks.md); none for a session whose ground truth has no joints (or no ground truth): the cell's
    other results stand."""
    from mmcsplat.pipeline.landmarks import track_landmarks
    from mmcsplat.plugin_api.errors import InputError, MissingFileError

    source, params = ("trc", {"path": spec.joints}) if spec.joints else ("synthetic", {"path": spec.ground_truth} if spec.ground_truth else {})
    try:
        carried = track_landmarks(cell_dir, source, params)
    except (InputError, MissingFileError):
        return {}
    accuracy = carried.info.get("accuracy_3d") or {}
    angles = carried.info.get("accuracy_joint_angles") or {}
    ranges = {}
    for kind in HEADLINE_ANGLES:
        sides = [carried.movement["joint_angles"].get(f"{side}_{kind}", {}).get("range_deg") for side in ("left", "right")]
        known = [value for value in sides if value is not None]
        ranges[f"{kind}_range_deg"] = sum(known) / len(known) if known else None
    return {"landmark_median_mm": accuracy.get("median_mm"), "landmark_moving_median_mm": accuracy.get("moving_median_mm"),
            "landmark_still_moving_median_mm": accuracy.get("still_moving_median_mm"),
            "joint_angle_median_error_deg": angles.get("median_deg"), "joint_angle_p90_error_deg": angles.get("p90_deg"), **ranges}
