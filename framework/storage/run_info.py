"""``RUN/run.json``: the record of a first-frame fit, typed and versioned.

The fit rewrites it at every checkpoint (``status`` "running"), at the end ("complete") or when the
training diverges ("diverged", with the ``error``); tracking, evaluation, rendering, reports and studies
read it through :class:`RunInfo` only, so a missing or garbled field is one error naming the file.

Versions: 0 is every run.json written before the field ``version`` existed (identical fields, no
``resumed_from``); 1 adds ``version`` and ``resumed_from``; 2 stores a local session's path relative to the
run directory, so a project folder copied or moved whole still works (read back as an absolute path). Fit settings absent from an older run's
``config_values`` read as the defaults they had when it was written (``fit.supersample`` 1, black
background). ``recording``, the fingerprint of the session's recording (:mod:`mmcsplat.storage.recording`), is
absent from runs fitted before it existed: unknown, read as ``None``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.run import RUN_INFO
from mmcsplat.storage.session.format import local_path

RUN_INFO_VERSION = 2
RUNNING, COMPLETE, DIVERGED = "running", "complete", "diverged"


def _names(value: Any) -> tuple[str, ...]:
    return tuple(str(item) for item in value)


@attrs.frozen
class RunInfo:
    """What a run directory's fit was, and where it stands."""

    #: "running", "complete" or "diverged".
    status: str = attrs.field(validator=attrs.validators.in_((RUNNING, COMPLETE, DIVERGED)))
    #: The session's URL, or its local path: absolute in memory, relative to the run directory on disk.
    session: str
    #: The configuration's name or file, and its values after overrides.
    config: str
    config_values: Mapping[str, Any]
    renderer: str
    #: The fitted session frame.
    frame: int = attrs.field(converter=int)
    train_cameras: tuple[str, ...] = attrs.field(converter=_names)
    heldout_cameras: tuple[str, ...] = attrs.field(converter=_names)
    #: Iterations done (the checkpoint's, while running).
    iterations: int = attrs.field(converter=int)
    num_gaussians: int = attrs.field(converter=int)
    wall_s: float = attrs.field(converter=float)
    scene_center: tuple[float, float, float] = attrs.field(converter=lambda value: tuple(float(x) for x in value))
    scene_scale: float = attrs.field(converter=float)
    #: Lowest and latest complete mean loss over a pass of the training cameras (docs/fit.md).
    loss_min: float | None = None
    loss_final: float | None = None
    error: str | None = None
    warnings: tuple[str, ...] = attrs.field(default=(), converter=_names)
    #: The iteration this run last resumed from (``None``: it never resumed).
    resumed_from: int | None = None
    #: The fingerprint of the recording fitted (``None``: unknown, a run or session older than fingerprints).
    recording: str | None = None
    version: int = RUN_INFO_VERSION

    @property
    def complete(self) -> bool:
        return self.status == COMPLETE

    @property
    def fit_table(self) -> Mapping[str, Any]:
        """The ``[fit]`` table the run was fitted with."""
        return self.config_values.get("fit", {})

    @property
    def supersample(self) -> int:
        """``fit.supersample`` (1 for runs fitted before it existed)."""
        return int(self.fit_table.get("supersample", 1))

    @property
    def background_value(self) -> Any:
        """``fit.background`` as written in the configuration (black when absent)."""
        return self.fit_table.get("background", (0.0, 0.0, 0.0))

    def to_json(self) -> dict[str, Any]:
        """The JSON object run.json holds."""
        return attrs.asdict(self, recurse=False, value_serializer=lambda _i, _f, value: list(value) if isinstance(value, tuple) else value)

    def write(self, run: Path) -> None:
        """Replace ``run``/run.json atomically, the session's local path relative to ``run``."""
        data = self.to_json()
        if local_path(self.session) is not None:
            data["session"] = os.path.relpath(os.path.abspath(self.session), os.path.abspath(run))
        write_json_atomic(Path(run) / RUN_INFO, data)

    @classmethod
    def read(cls, run: Path) -> RunInfo:
        """The run.json of the run directory ``run``; an error naming the file when it is missing,
        unreadable, of a newer version or lacks a field."""
        path = Path(run) / RUN_INFO
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError as error:
            raise MissingFileError(f"{path} does not exist: {Path(run)} is not a fit run directory") from error
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise InputError(f"{path} is not readable JSON ({error})") from error
        info = cls.from_json(data, path)
        if local_path(info.session) is None or os.path.isabs(info.session):
            return info
        return attrs.evolve(info, session=os.path.normpath(os.path.join(os.path.abspath(run), info.session)))

    @classmethod
    def from_json(cls, data: Any, source: Path | str) -> RunInfo:
        """A record from run.json's object; ``source`` names it in errors."""
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected a JSON object, got {type(data).__name__}")
        version = data.get("version", 0)
        if not isinstance(version, int) or version > RUN_INFO_VERSION:
            raise InputError(f"{source}: run.json version {version!r} is newer than this mmcsplat reads ({RUN_INFO_VERSION}); upgrade mmcsplat")
        fields = {field.name for field in attrs.fields(cls)}
        values = {key: value for key, value in data.items() if key in fields} | {"version": RUN_INFO_VERSION}
        try:
            return cls(**values)
        except (TypeError, ValueError) as error:
            missing = sorted(field.name for field in attrs.fields(cls) if field.default is attrs.NOTHING and field.name not in data)
            detail = f"missing {', '.join(missing)}" if missing else str(error)
            raise InputError(f"{source}: not a valid run record ({detail})") from error
