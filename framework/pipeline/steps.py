"""The step runner of the jobs that chain the pipeline — the demo, ``mmcsplat run`` and a study's cells: a
list of steps run in order, each skipped when its outputs are already there, so a rerun resumes; the
settings a folder was made with, recorded so that a rerun with others is refused rather than mixing two
jobs in one folder; a store made in a hidden sibling and renamed into place, so a half-made one never
reads as made. It sits in ``pipeline`` so that ``studies`` (below ``jobs``) runs its cells with it too.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.plugin_api.errors import InputError, MmcsplatError
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.run import RUN_INFO


@attrs.frozen
class Step:
    """One step: ``action`` runs unless ``done()`` — asked when the step's turn comes, after the steps
    before it have made their outputs."""

    name: str
    done: Callable[[], bool]
    action: Callable[[], object]


@attrs.frozen
class StepTime:
    """One step's wall time; ``reused`` when its outputs were already there."""

    name: str
    seconds: float
    reused: bool


#: attrs metadata key of a settings field added after folders were made without it: the value it had in effect there.
BEFORE_FIELD = "before"


@attrs.frozen
class SettingsRecord:
    """``path`` (e.g. OUT/demo.json) records the ``settings`` a job's folder is made with. It is written only
    once a step has succeeded, so a first run that fails before making anything does not tie its folder to
    its settings (a rerun with corrected ones goes ahead). ``before`` holds, for settings added after
    folders were made without them, the value those folders had in effect: a folder whose record lacks
    such a setting resumes when the value is unchanged. A setting without one is taken as changed.
    ``same_as`` holds, for a setting that can be written two ways (``auto`` and the number it came to), a
    function giving what a value stands for; two values that stand for the same one match."""

    path: Path
    settings: dict[str, Any]
    before: dict[str, Any] = attrs.field(factory=dict)
    same_as: dict[str, Callable[[Any], Any]] = attrs.field(factory=dict)

    @classmethod
    def of(cls, path: Path, settings: Any, same_as: dict[str, Callable[[Any], Any]] | None = None) -> SettingsRecord:
        """The record at ``path`` of the attrs instance ``settings``, as JSON reads it back; a field's
        :data:`BEFORE_FIELD` metadata is its ``before``."""
        before = {field.name: field.metadata[BEFORE_FIELD] for field in attrs.fields(type(settings)) if BEFORE_FIELD in field.metadata}
        return cls(Path(path), json.loads(json.dumps(attrs.asdict(settings))), json.loads(json.dumps(before)), dict(same_as or {}))

    def check(self) -> None:
        """Refuse when the folder was made with other settings, naming each that differs."""
        if not self.path.exists():
            return
        made = {**self.before, **json.loads(self.path.read_text())}

        def differs(key: str) -> bool:
            was, now = made.get(key), self.settings.get(key)
            if was == now:
                return False
            meaning = self.same_as.get(key)
            return meaning is None or meaning(was) != meaning(now)

        changed = sorted(key for key in self.settings.keys() | made.keys() if differs(key))
        if changed:
            raise InputError(f"{self.path.parent} was made with other settings ({self.path}: "
                             + ", ".join(f"{key} {made.get(key)!r}, now {self.settings.get(key)!r}" for key in changed)
                             + "): use another --out, the same settings to resume, or delete it")

    def write(self) -> None:
        """Record the settings, unless already recorded."""
        if not self.path.exists():
            write_json_atomic(self.path, self.settings)


def run_steps(job: str, steps: Sequence[Step], log: Callable[[str], None] | None = None, record: SettingsRecord | None = None) -> tuple[StepTime, ...]:
    """Run ``steps`` in order, skipping those done; ``log`` gets ``[job] name done (… s)`` per step.
    ``record`` is checked before the first step and written once one has succeeded."""
    if record is not None:
        record.check()
    times = []
    for step in steps:
        began = time.perf_counter()
        done = step.done()
        if not done:
            step.action()
        if record is not None:
            record.write()
        timed = StepTime(step.name, time.perf_counter() - began, done)
        if log is not None:
            log(f"[{job}] {step.name} {'already done' if done else 'done'} ({timed.seconds:.1f} s)")
        times.append(timed)
    return tuple(times)


def fresh(outputs: Iterable[Path], inputs: Iterable[Path] = ()) -> bool:
    """Whether every output exists and none is older than any input (a step made from them is done)."""
    outputs = list(outputs)
    if not all(path.exists() for path in outputs):
        return False
    newest = max((path.stat().st_mtime_ns for path in inputs), default=0)
    return all(path.stat().st_mtime_ns >= newest for path in outputs)


def fit_complete(run: Path) -> bool:
    """Whether ``run`` holds a complete first-frame fit (its run.json says so)."""
    from mmcsplat.storage.run_info import RunInfo  # the session store's format with it: not for every command's start

    return (Path(run) / RUN_INFO).exists() and RunInfo.read(run).complete


def made_in_place(target: Path, make: Callable[[Path], None]) -> None:
    """``make(partial)`` builds ``target`` in the hidden sibling ``.NAME.partial`` (a leftover of an
    interrupted one removed first), which is then renamed into place; a ``make`` that fails or is
    interrupted leaves nothing (the next one starts afresh anyway). A user-facing error that names the
    partial folder is raised again, of the same type, naming ``target``: the user never asked for the
    hidden folder, and it is gone."""
    partial = target.with_name(f".{target.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        make(partial)
    except BaseException as error:
        shutil.rmtree(partial, ignore_errors=True)
        if isinstance(error, MmcsplatError) and str(partial) in str(error):  # its message is its one argument (errors.py)
            raise type(error)(str(error).replace(str(partial), str(target))) from error
        raise
    os.replace(partial, target)
