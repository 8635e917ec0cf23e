"""A leave-one-camera-out run (``mmcsplat fit --folds``): one fit per held-out camera in ``RUN/<camera>/``,
and ``RUN/folds.json`` listing those cameras, written before the first fold is fitted. With the plan on
disk a fold killed before its first checkpoint, or never reached, is known to be missing: evaluate
refuses (or labels) the run instead of averaging the folds that happen to be there."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.run import FOLDS_FILE


def write_fold_plan(run: Path, cameras: Sequence[str]) -> None:
    """Record (atomically) that ``run`` holds one fold per camera of ``cameras``, after the folds of an
    earlier plan: a rerun naming other cameras adds folds, it never drops one from the averages."""
    planned = planned_folds(run) or ()
    Path(run).mkdir(parents=True, exist_ok=True)
    write_json_atomic(Path(run) / FOLDS_FILE, {"folds": [*planned, *(name for name in cameras if name not in planned)]})


def planned_folds(run: Path) -> tuple[str, ...] | None:
    """The folds planned for ``run``; ``None`` when it has no plan (a single fit, or folds fitted before
    plans were written)."""
    path = Path(run) / FOLDS_FILE
    if not path.is_file():
        return None
    try:
        folds = json.loads(path.read_text(encoding="utf-8"))["folds"]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as error:
        raise InputError(f"{path} is not a fold plan ({type(error).__name__}: {error}): delete it and run `mmcsplat fit --folds` with "
                         "every fold again") from None
    if not isinstance(folds, list) or not all(isinstance(name, str) and name for name in folds):
        raise InputError(f"{path}: 'folds' must be a list of camera names: delete it and run `mmcsplat fit --folds` with every fold again")
    return tuple(folds)
