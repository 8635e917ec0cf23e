"""The sessions a study reads, made ready before any cell runs: a synthetic capture synthesized and
ingested, a segmenter run on a copy (the user's own session is never modified). Each step is skipped when
its output is already there, so a restarted study reuses them; every output appears atomically."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from .atomic import write_json_atomic
from .config import PluginChoice
from .store import IncompleteSessionError, SessionReader
from .study import SessionPlan, StudyError

#: Written beside a prepared session once it is complete: the identity it was made from.
IDENTITY_SUFFIX = ".json"


def prepare_session(plan: SessionPlan, progress: bool = True) -> None:
    """Make ``plan.url`` ready (nothing to do for a stored session read in place)."""
    if plan.segmenter is None:
        return
    target = Path(plan.url)
    identity_file = target.with_suffix(IDENTITY_SUFFIX)
    if identity_file.exists():
        if json.loads(identity_file.read_text()) != plan.identity:
            raise StudyError(f"{target} was prepared from other settings ({identity_file}): use a new --out or delete it")
        return
    source = _synthesized(plan, target.parent, progress) if plan.spec.synthetic is not None else plan.spec.path
    if "://" in str(source):
        raise StudyError(f"session {plan.spec.name!r}: segmenting a copy needs a local session, not the URL {source}")
    _segmented_copy(Path(source), target, plan.segmenter, progress)
    write_json_atomic(identity_file, plan.identity)


def _synthesized(plan: SessionPlan, folder: Path, progress: bool) -> Path:
    """FOLDER/capture (synthesized) ingested into FOLDER/ingested.zarr; both reused when complete."""
    from .datasets.synthetic.synthesize import SynthConfig, synthesize
    from .ingest import ingest

    capture, ingested = folder / "capture", folder / "ingested.zarr"
    recorded = folder / "synthetic.json"
    if recorded.exists() and json.loads(recorded.read_text()) != dict(plan.spec.synthetic or {}):
        raise StudyError(f"{capture} was synthesized with other settings ({recorded}): use a new --out or delete {folder}")
    folder.mkdir(parents=True, exist_ok=True)
    if not (capture / "calibration.toml").exists():
        synthesize(capture, SynthConfig(**plan.spec.synthetic), overwrite=True, progress=progress)
        write_json_atomic(recorded, dict(plan.spec.synthetic or {}))
    if not _complete(ingested):
        ingest(capture, ingested, holdout=list(plan.spec.heldout), overwrite=True, progress=progress)
    return ingested


def _segmented_copy(source: Path, target: Path, segmenter: PluginChoice, progress: bool) -> None:
    """``source`` copied, segmented by ``segmenter`` and renamed into place as ``target``."""
    from .commands.segment import segment_session

    if not _complete(source):
        raise StudyError(f"{source} is not a complete session store")
    partial = target.with_name(f".{target.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    shutil.rmtree(target, ignore_errors=True)  # a copy whose identity file was never written
    shutil.copytree(source, partial)
    segment_session(partial, segmenter.name, segmenter.params, progress=progress)
    os.replace(partial, target)


def _complete(url: Path) -> bool:
    """Whether ``url`` holds a committed session."""
    if not url.exists():
        return False
    try:
        SessionReader(url)
    except IncompleteSessionError:
        return False
    return True
