"""Unfinished is never final: what of a run directory is not finished — a fit not complete (killed, still
running, diverged), a tracking stopped half way, another process writing the run now — refused by the
commands that score or hand on a run (evaluate, report, landmarks, export) unless the user asks for
``--allow-incomplete``, which labels their outputs instead."""

from __future__ import annotations

from pathlib import Path

import filelock

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import remove_local_tree
from mmcsplat.storage.locking import RUN_LOCK, BusyError
from mmcsplat.storage.run import MADE_OF_THE_MODEL, TRACKING_UNFINISHED
from mmcsplat.storage.run_info import RunInfo

#: The one spelling of the option that accepts unfinished work, labelled.
ALLOW_INCOMPLETE = "--allow-incomplete"


class UnfinishedRunError(InputError):
    """A run whose fit or tracking is not finished, used where only finished work may be."""


def require_not_busy(run: Path) -> None:
    """Refuse a run directory another mmcsplat process holds (a fit or track writing it now)."""
    lock = filelock.FileLock(Path(run) / RUN_LOCK, timeout=0)
    try:
        lock.acquire()
    except filelock.Timeout as error:
        raise BusyError(f"run {run} is being written by another mmcsplat process (lock {Path(run) / RUN_LOCK}): wait for it to "
                        "finish; nothing is scored or written for a run in progress") from error
    except OSError:  # a read-only run directory: nobody can be writing it
        return
    lock.release()
    (Path(run) / RUN_LOCK).unlink(missing_ok=True)


def unfinished_work(run: Path, info: RunInfo) -> list[str]:
    """What of the run directory ``run`` (whose run.json is ``info``) is not finished, each with what to do."""
    run = Path(run)
    problems = []
    if not info.complete:
        problems.append(f"its fit is {info.status!r} at iteration {info.iterations} (run.json), not complete: run the same "
                        "`mmcsplat fit` again to resume it")
    if (run / TRACKING_UNFINISHED).exists():
        problems.append(f"its tracking was stopped or failed before it finished ({run / TRACKING_UNFINISHED}): run `mmcsplat track {run}` "
                        "again (it resumes; add --overwrite where older tracks are in the way)")
    return problems


def require_finished(run: Path, info: RunInfo, allow_incomplete: bool) -> list[str]:
    """Refuse a run another process is writing, and one with unfinished work unless ``allow_incomplete``;
    returns the unfinished work (empty for a finished run), for the outputs to be labelled with."""
    require_not_busy(run)
    problems = unfinished_work(run, info)
    if problems and not allow_incomplete:
        raise UnfinishedRunError(f"run {run} is unfinished: {'; '.join(problems)} (or pass {ALLOW_INCOMPLETE} to label the outputs incomplete)")
    return problems


def remove_made_before(run: Path) -> list[str]:
    """Remove what was made of ``run``'s Gaussians (:data:`~mmcsplat.storage.run.MADE_OF_THE_MODEL`: scores,
    landmarks, renders, report) once they change — new tracks, a fit resumed — and return the names removed:
    a report of the tracks replaced, of the fit alone (one frame of a run that now has many) or of a fit stopped
    half way (renders carry no label) would otherwise read as the run's. Its writer holds the run's lock."""
    removed = []
    for name in MADE_OF_THE_MODEL:
        path = Path(run) / name
        if path.exists() or path.is_symlink():
            remove_local_tree(path)
            removed.append(name)
    return removed
