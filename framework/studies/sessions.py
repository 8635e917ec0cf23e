"""The sessions a study reads, made ready before any cell runs: a synthetic capture synthesized and
ingested, a capture folder made into a session as ``mmcsplat run`` makes it, a copy modified (cameras
dropped, one camera's extrinsics perturbed) and segmented (the user's own session is never modified: it
only gains its optical flow), and the optical flow computed where a cell's dynamics reads it. Each step is skipped when its output is already
there, so a restarted study reuses them; every output appears atomically."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.configuration.config import PluginChoice
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.session import IncompleteSessionError, SessionReader, SessionUpdater
from mmcsplat.studies.spec import SessionPlan, SessionSpec, StudyError

#: Written beside a prepared session once it is complete: the identity it was made from.
IDENTITY_SUFFIX = ".json"


def prepare_session(plan: SessionPlan, progress: bool = True) -> None:
    """Make ``plan.url`` ready (nothing to do for a stored session read in place)."""
    if plan.in_place:
        return
    target = Path(plan.url)
    identity_file = target.with_suffix(IDENTITY_SUFFIX)
    if identity_file.exists():
        if json.loads(identity_file.read_text()) != plan.identity:
            raise StudyError(f"{target} was prepared from other settings ({identity_file}): use a new --out or delete it")
        return
    if plan.spec.capture is not None:
        _captured(plan.spec.capture, target, plan.segmenter, progress)
        write_json_atomic(identity_file, plan.identity)
        return
    source = _synthesized(plan, target.parent, progress) if plan.spec.synthetic is not None else plan.spec.path
    if "://" in str(source):
        raise StudyError(f"session {plan.spec.name!r}: copying it (to segment or modify) needs a local session, not the URL {source}")
    _prepared_copy(Path(source), target, plan.spec, plan.segmenter, progress)
    write_json_atomic(identity_file, plan.identity)


def prepare_flow(plan: SessionPlan, preset: str, progress: bool = True) -> None:
    """Give the session ``plan.url`` its optical flow with the DIS ``preset`` (once: a complete flow is kept,
    an interrupted one resumed), for the cells whose dynamics reads it. A stored session read in place gets
    it as ``mmcsplat flow`` would give it (stored beside its frames, which stay as they are); a remote one
    (a URL) must already hold it."""
    from mmcsplat.pipeline.flow import compute_flow, flow_complete

    if flow_complete(plan.url, preset=preset):
        return
    if "://" in plan.url:
        raise StudyError(f"session {plan.spec.name!r} ({plan.url}) has no complete optical flow (DIS preset {preset!r}), which a variant's "
                         f"dynamics reads, and the study does not write into a remote session: run `mmcsplat flow` on it first")
    compute_flow(plan.url, preset=preset, progress=progress)


def _captured(capture: dict, target: Path, segmenter: PluginChoice | None, progress: bool) -> None:
    """The capture folder made into the session ``target`` as ``mmcsplat run`` makes its own (ingested, masks
    and plates; the masks ``segmenter``'s when given, as with ``run --segmenter``), in a hidden sibling renamed
    into place."""
    from mmcsplat.pipeline.capture_session import keypoint_source, keypoints_with, prepare_capture_session
    from mmcsplat.pipeline.segment import BuiltSegmenter
    from mmcsplat.pipeline.steps import made_in_place

    reader = capture.get("reader", {})  # the reader's options (run's --reader-set); its naming ones name the keypoint files too

    def make(partial: Path) -> None:
        prepare_capture_session(Path(capture["path"]), partial, calibration=Path(capture["calibration"]) if capture["calibration"] else None,
                                units=capture["units"], frames=slice(*capture["frames"]) if capture["frames"] else None, scale=capture["scale"],
                                cameras=capture["cameras"] or None, holdout=capture["holdout"],
                                source=keypoints_with(keypoint_source(Path(capture["keypoints"])), {}, reader) if capture["keypoints"] else None,
                                segmenter=BuiltSegmenter.of(segmenter) if segmenter else None, reader_options=reader or None, progress=progress)

    made_in_place(target, make)


def _synthesized(plan: SessionPlan, folder: Path, progress: bool) -> Path:
    """FOLDER/capture (synthesized) ingested into FOLDER/ingested.zarr; both reused when complete (the ingest when it
    holds out the cameras the session does)."""
    from mmcsplat.pipeline.ingest import ingest
    from mmcsplat.synthetic.synthesize import SynthConfig, synthesize

    capture, ingested = folder / "capture", folder / "ingested.zarr"
    recorded = folder / "synthetic.json"
    if recorded.exists() and json.loads(recorded.read_text()) != dict(plan.spec.synthetic or {}):
        raise StudyError(f"{capture} was synthesized with other settings ({recorded}): use a new --out or delete {folder}")
    folder.mkdir(parents=True, exist_ok=True)
    if not (capture / "calibration.toml").exists():
        synthesize(capture, SynthConfig(**plan.spec.synthetic), overwrite=True, progress=progress)
        write_json_atomic(recorded, dict(plan.spec.synthetic or {}))
    # Ingested again when the held-out cameras changed: a copy made from it holds out what it holds out.
    if not _complete(ingested) or set(SessionReader(ingested).heldout) != set(plan.spec.heldout):
        ingest(capture, ingested, holdout=list(plan.spec.heldout), overwrite=True, progress=progress)
    return ingested


def _prepared_copy(source: Path, target: Path, spec: SessionSpec, segmenter: PluginChoice | None, progress: bool) -> None:
    """``source`` copied, modified as ``spec`` says, segmented by ``segmenter`` (if any) and renamed into
    place as ``target``."""
    from mmcsplat.pipeline.segment import segment_session
    from mmcsplat.pipeline.steps import made_in_place

    if not _complete(source):
        raise StudyError(f"{source} is not a complete session store")

    def make(partial: Path) -> None:
        shutil.copytree(source, partial)
        if spec.modifications:
            _modify(partial, spec)
        if segmenter is not None:
            segment_session(partial, segmenter.name, segmenter.params, progress=progress)

    shutil.rmtree(target, ignore_errors=True)  # a copy whose identity file was never written
    made_in_place(target, make)


def _modify(path: Path, spec: SessionSpec) -> None:
    """Keep only ``spec.cameras`` (and only those held out) and perturb ``spec.perturb``'s camera, in
    the session copy at ``path``, through the session updater; the arrays of dropped cameras are deleted."""
    with SessionUpdater(path) as updater:  # an error below aborts it: the copy is left as it was
        names = list(updater.camera_names)
        keep = list(spec.cameras) if spec.cameras is not None else names
        named = keep + ([spec.perturb.camera] if spec.perturb is not None else [])
        unknown = [name for name in named if name not in names]
        if unknown:
            raise StudyError(f"session {spec.name!r}: no camera {unknown[0]!r} to keep or perturb; its cameras: {names}")
        if spec.perturb is not None and spec.perturb.camera not in keep:
            raise StudyError(f"session {spec.name!r}: perturbs camera {spec.perturb.camera!r}, which its 'cameras' drop")
        updater.keep_cameras([perturbed(camera, spec.perturb.degrees) if spec.perturb is not None and camera.name == spec.perturb.camera else camera
                              for camera in updater.cameras if camera.name in keep])


def perturbed(camera: Camera, degrees: float) -> Camera:
    """``camera`` turned by ``degrees`` about its own y axis (image down) through its centre: world
    points map to ``Ry @ (R x + t)``, so R becomes ``Ry R`` and t becomes ``Ry t``."""
    angle = np.radians(degrees)
    turn = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    return attrs.evolve(camera, R=turn @ camera.R, t=turn @ camera.t)


def _complete(url: Path) -> bool:
    """Whether ``url`` holds a committed session."""
    if not url.exists():
        return False
    try:
        SessionReader(url)
    except IncompleteSessionError:
        return False
    return True
