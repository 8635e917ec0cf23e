"""Studies: a TOML file naming sessions, folds, seeds and variants, expanded into cells.

A cell is one first-frame fit (plus tracking when its variant has a ``[dynamics]`` table) of one variant
on one session, with one held-out camera (fold), one seed and one renderer backend. Its key is a hash of
everything that decides its result — the resolved configuration (base configuration after every
override), the session's identity, the fold, the seed and the backend — so a cell runs once, however many
variants resolve to it and however often the study is restarted. docs/studies.md describes the format.
"""

from __future__ import annotations

import hashlib
import inspect
import itertools
import json
import os
import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.configuration.config import Config, ConfigError, PluginChoice, load_config, set_value
from mmcsplat.configuration.registry import PluginError, Registry, default_registry
from mmcsplat.plugin_api.errors import InputError, PluginUnavailableError
from mmcsplat.storage.calibration import UNIT_CHOICES
from mmcsplat.synthetic.defaults import SYNTHETIC_HELDOUT, SYNTHETIC_SEGMENTER

#: Bump when the meaning of a key's payload changes: every cell then runs again.
KEY_VERSION = 1
#: Plugin kinds a variant may replace wholesale with a table of its own.
VARIANT_PLUGIN_TABLES = ("renderer", "initializer", "densifier", "dynamics")
STUDY_KEYS = {"study", "sessions", "variant"}
HEADER_KEYS = {"name", "description", "folds", "seeds", "backends", "set"}
SESSION_KEYS = {"path", "synthetic", "capture", "segmenter", "heldout", "folds", "ground_truth", "cameras", "perturb"}
#: What a ``capture`` table may hold: the capture folder and what ``mmcsplat run`` takes to make a session of it.
CAPTURE_KEYS = {"path", "calibration", "units", "scale", "frames", "cameras", "holdout", "keypoints", "joints", "reader"}
#: Session keys a capture session leaves to its ``capture`` table (cameras, joints); its ``segmenter`` is ``run --segmenter``'s.
NOT_FOR_CAPTURES = ("ground_truth", "cameras", "perturb")
VARIANT_KEYS = {"name", "config", "set", "grid", "segmenter", *VARIANT_PLUGIN_TABLES}
#: Synthesis settings added after studies were first keyed: left out of identities at these defaults,
#: so that existing study directories keep their cells.
LATER_SYNTHETIC_DEFAULTS = {"slide": 0.0, "motion": "natural"}


class StudyError(InputError):
    """A study file that cannot be read or expanded; the message names the file, variant or session."""


@attrs.frozen
class Perturbation:
    """Wrong extrinsics for one camera: ``camera`` turned by ``degrees`` about its own vertical (image y)
    axis through its centre, as a calibration that is off by that much would store it."""

    camera: str
    degrees: float


@attrs.frozen
class SessionSpec:
    """One ``[sessions.NAME]`` table: a stored session (``path``: a path or URL), one to synthesize
    (``synthetic``: :class:`~mmcsplat.synthetic.synthesize.SynthConfig` fields, and the cameras
    held out at its ingest) or a capture folder to make one of as ``mmcsplat run`` does (``capture``: its
    settings, paths resolved and defaults filled, with ``joints``, the TRC its carried joints are scored
    against, or ``None``), the segmenter to run on a copy of it (on a capture: to make its masks, as
    ``run --segmenter`` does), its folds when they differ from the
    study's, and ground truth for tracking. ``cameras`` (the only cameras kept) and ``perturb`` (one
    camera's extrinsics rotated: :class:`Perturbation`) make the study read a modified copy of it —
    failure regimes for ``mmcsplat stability``."""

    name: str
    path: str | None = None
    synthetic: Mapping[str, Any] | None = None
    heldout: tuple[str, ...] = SYNTHETIC_HELDOUT
    segmenter: PluginChoice | None = None
    folds: tuple[str, ...] | None = None
    ground_truth: str | None = None
    cameras: tuple[str, ...] | None = None
    perturb: Perturbation | None = None
    capture: Mapping[str, Any] | None = None

    @property
    def modifications(self) -> dict[str, Any]:
        """What the study changes in its copy of the session (empty: none), as part of its identity."""
        changes: dict[str, Any] = {}
        if self.cameras is not None:
            changes["cameras"] = list(self.cameras)
        if self.perturb is not None:
            changes["perturb"] = attrs.asdict(self.perturb)
        return changes


@attrs.frozen
class Variant:
    """One row of the study: a name, its resolved configuration (before seed and backend) and the
    segmenter it asks for instead of the session's."""

    name: str
    config: Config
    segmenter: PluginChoice | None = None


@attrs.frozen
class Study:
    """A parsed study file."""

    name: str
    source: str
    description: str
    text: str
    sessions: tuple[SessionSpec, ...]
    folds: tuple[str, ...]
    seeds: tuple[int, ...]
    backends: tuple[str, ...]
    variants: tuple[Variant, ...]


@attrs.frozen
class SessionPlan:
    """Where a cell reads a session (``url``) and what identifies it in cell keys (``identity``: the
    stored session's address, or the synthesis settings, the modifications and the segmenter). With a
    segmenter or modifications the study writes the session under OUT/sessions (synthesized, or
    copied, then modified and segmented); without them (a stored session only) it is read in place."""

    spec: SessionSpec
    segmenter: PluginChoice | None
    url: str
    identity: Mapping[str, Any]

    @property
    def in_place(self) -> bool:
        """Whether the cells read the stored session itself (the study adds at most its optical flow to it)."""
        return self.spec.path is not None and self.segmenter is None and not self.spec.modifications


@attrs.frozen
class CellSpec:
    """Everything a worker needs to run one cell; plain data, so it pickles to processes and Ray tasks."""

    config_source: str
    config_values: Mapping[str, Any]
    session_url: str
    session_identity: Mapping[str, Any]
    holdout: tuple[str, ...] | None
    seed: int
    backend: str
    ground_truth: str | None = None
    #: The TRC of a capture session's joints, which the cell's carried joints are scored against.
    joints: str | None = None
    #: The DIS preset of the session's optical flow that the cell's dynamics reads (``None``: it reads none).
    flow: str | None = None

    @property
    def key(self) -> str:
        return cell_key(self.config_values, self.session_identity, self.holdout, self.seed, self.backend, self.flow)

    @property
    def config(self) -> Config:
        return Config(self.config_source, self.config_values)

    @property
    def fit_config(self) -> Config:
        """The configuration without its ``[dynamics]`` table: all that the first-frame fit reads."""
        return Config(self.config_source, {name: table for name, table in self.config_values.items() if name != "dynamics"})

    @property
    def fit_key(self) -> str:
        """The key of the cell's first-frame fit: equal for cells that differ only in their dynamics."""
        return cell_key(self.fit_config.values, self.session_identity, self.holdout, self.seed, self.backend)

    @property
    def has_dynamics(self) -> bool:
        return "dynamics" in self.config_values


@attrs.frozen
class Cell:
    """One row of the study's results: which variant, session, fold, seed and backend made ``spec``."""

    variant: str
    session: str
    fold: str
    seed: int
    backend: str
    spec: CellSpec
    plan: SessionPlan


def cell_key(config_values: Mapping[str, Any], session_identity: Mapping[str, Any], holdout: Sequence[str] | None,
             seed: int, backend: str, flow: str | None = None) -> str:
    """The hex key of a cell: a SHA-256 of its canonical JSON (sorted keys), independent of the study's
    variant names and of the order in which tables were written. The flow preset a cell reads is in the
    payload only when it reads one, so cells keyed before studies computed flow keep their keys (those of
    them that asked for flow-guided prediction ran without flow, and run again)."""
    payload = {"version": KEY_VERSION, "config": config_values, "session": session_identity,
               "holdout": list(holdout) if holdout is not None else None, "seed": seed, "backend": backend,
               **({"flow": flow} if flow is not None else {})}
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


# ------------------------------------------------------------------------------------------- loading


def builtin_study_names() -> list[str]:
    """Names of the studies shipped with mmcsplat (``studies/*.toml``, file stem with ``_`` as ``-``)."""
    folder = resources.files("mmcsplat.studies.builtin")
    return sorted(entry.name[: -len(".toml")].replace("_", "-") for entry in folder.iterdir() if entry.name.endswith(".toml"))


def _read(name_or_path: str | Path) -> tuple[str, str, Path | None, str]:
    """(text, source, folder for relative paths, default name) of a study file or built-in study."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise StudyError(f"study file {path} does not exist")
        return path.read_text(encoding="utf-8"), str(path), path.resolve().parent, path.stem
    resource = resources.files("mmcsplat.studies.builtin").joinpath(f"{str(name_or_path).replace('-', '_')}.toml")
    if not resource.is_file():
        known = ", ".join(builtin_study_names()) or "none"
        raise StudyError(f"unknown study {str(name_or_path)!r}: not a file, and the built-in ones are {known}")
    return resource.read_text(encoding="utf-8"), f"built-in study {name_or_path!r}", None, str(name_or_path)


def load_study(name_or_path: str | Path, registry: Registry | None = None) -> Study:
    """Parse and check a study file (or a built-in study by name): every variant's configuration loads,
    its overrides apply, its plugins are registered and its ``[fit]`` keys are known."""
    text, source, folder, default_name = _read(name_or_path)
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise StudyError(f"{source}: invalid TOML: {error}") from error
    _check_keys(document, STUDY_KEYS, source, "top-level")
    header = _table(document.get("study", {}), f"{source}: [study]")
    _check_keys(header, HEADER_KEYS, source, "[study]")
    shared = flatten(_table(header.get("set", {}), f"{source}: [study] set"))
    sessions = tuple(_session(name, _table(table, f"{source}: [sessions.{name}]"), source, folder)
                     for name, table in _table(document.get("sessions"), f"{source}: [sessions]", required=True).items())
    if not sessions:
        raise StudyError(f"{source}: no [sessions.NAME] table: name at least one session")
    rows = document.get("variant")
    if not isinstance(rows, list) or not rows:
        raise StudyError(f"{source}: no [[variant]] table: name at least one variant")
    variants = [v for index, row in enumerate(rows) for v in _variants(_table(row, f"{source}: [[variant]] #{index + 1}"), index, shared, source, folder)]
    names = [variant.name for variant in variants]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise StudyError(f"{source}: variant names must be unique; repeated: {duplicates}")
    study = Study(
        name=str(header.get("name", default_name)),
        source=source,
        description=str(header.get("description", "")),
        text=text,
        sessions=sessions,
        folds=_strings(header.get("folds", []), f"{source}: [study] folds"),
        seeds=_integers(header.get("seeds", [0]), f"{source}: [study] seeds"),
        backends=_strings(header.get("backends", []), f"{source}: [study] backends"),
        variants=tuple(variants),
    )
    _validate(study, registry or default_registry())
    return study


#: What a name from a study file may be, since it becomes a folder under the study's output.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]*")


def _session(name: str, table: Mapping[str, Any], source: str, folder: Path | None) -> SessionSpec:
    where = f"{source}: [sessions.{name}]"
    if not SAFE_NAME.fullmatch(name) or ".." in name:
        raise StudyError(f"{where}: a session name becomes a folder under --out: use letters, digits, '_', '-', '.' and '+' "
                         f"(no path separators, '..' or leading dot), not {name!r}")
    _check_keys(table, SESSION_KEYS, source, f"[sessions.{name}]")
    if sum(kind in table for kind in ("path", "synthetic", "capture")) != 1:
        raise StudyError(f"{where} needs exactly one of 'path' (a stored session), 'synthetic' (a table of synthesis settings) or "
                         "'capture' (a table naming a capture folder)")
    if "heldout" in table and "synthetic" not in table:
        raise StudyError(f"{where}: 'heldout' applies to synthetic sessions only (a stored session has its own; a capture's is its "
                         "capture table's holdout)")
    segmenter = _segmenter(table["segmenter"], where) if "segmenter" in table else None
    folds = _strings(table["folds"], f"{where} folds") if "folds" in table else None
    ground_truth = _resolve_path(table["ground_truth"], folder, f"{where} ground_truth") if "ground_truth" in table else None
    cameras = _strings(table["cameras"], f"{where} cameras") if "cameras" in table else None
    perturb = _perturbation(table["perturb"], where) if "perturb" in table else None
    if "capture" in table:
        misplaced = [key for key in NOT_FOR_CAPTURES if key in table]
        if misplaced:
            raise StudyError(f"{where}: {misplaced} do not apply to a capture session (it is made as `mmcsplat run` makes it: "
                             "its cameras, holdout and joints go in its capture table)")
        return SessionSpec(name, heldout=(), segmenter=segmenter, folds=folds,
                           capture=capture_settings(_table(table["capture"], f"{where} capture"), where, folder))
    if "synthetic" in table:
        settings = synthetic_settings(_table(table["synthetic"], f"{where} synthetic"), where)
        return SessionSpec(name, None, settings, _strings(table.get("heldout", list(SYNTHETIC_HELDOUT)), f"{where} heldout"),
                           segmenter or PluginChoice("segmenter", SYNTHETIC_SEGMENTER), folds, ground_truth, cameras, perturb)
    path = table["path"]
    if not isinstance(path, str) or not path:
        raise StudyError(f"{where} path must be a non-empty string")
    url = path if "://" in path else _resolve_path(path, folder, f"{where} path")
    return SessionSpec(name, url, None, (), segmenter, folds, ground_truth, cameras, perturb)


def _perturbation(value: Any, where: str) -> Perturbation:
    table = _table(value, f"{where} perturb")
    degrees = table.get("degrees")
    if set(table) != {"camera", "degrees"} or not isinstance(table["camera"], str) or not isinstance(degrees, (int, float)) or isinstance(degrees, bool):
        raise StudyError(f"{where} perturb must be a table {{ camera = NAME, degrees = ANGLE }}, got {dict(table)!r}")
    return Perturbation(table["camera"], float(degrees))


def synthetic_settings(table: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Every synthesis setting, defaults filled in, so that equal captures get equal identities."""
    from mmcsplat.synthetic.synthesize import SynthConfig

    try:
        settings = attrs.asdict(SynthConfig(**table))
        return {key: value for key, value in settings.items() if key not in LATER_SYNTHETIC_DEFAULTS or value != LATER_SYNTHETIC_DEFAULTS[key]}
    except (TypeError, ValueError) as error:
        known = [field.name for field in attrs.fields(SynthConfig)]
        raise StudyError(f"{where} synthetic: {error} (settings: {known})") from error


def capture_settings(table: Mapping[str, Any], where: str, folder: Path | None) -> dict[str, Any]:
    """A capture table with its paths resolved (relative ones from the study file's folder) and every default
    filled in as ``mmcsplat run`` fills it — the scale it ingests at, the capture's folder of 2D keypoints and its
    TRC of joints when it has them (:func:`~mmcsplat.pipeline.capture_session.keypoint_folder`,
    :func:`~mmcsplat.pipeline.capture_session.joints_file`) — so equal captures get equal identities."""
    from mmcsplat.pipeline.capture_session import DEFAULT_SCALE, joints_file, keypoint_folder, start_with_joints
    from mmcsplat.pipeline.image_scale import AUTO_SCALE
    from mmcsplat.pipeline.ingest import capture_reader

    _check_keys(table, CAPTURE_KEYS, where, "capture")
    if "path" not in table:
        raise StudyError(f"{where} capture needs 'path': the capture folder")
    capture = Path(_resolve_path(table["path"], folder, f"{where} capture path"))
    if not capture.is_dir():
        raise StudyError(f"{where} capture path {capture} is not a folder")
    paths = {key: _resolve_path(table[key], folder, f"{where} capture {key}") if key in table else None
             for key in ("calibration", "keypoints", "joints")}
    frames = table.get("frames", [])
    if not isinstance(frames, list) or len(frames) not in (0, 2, 3) or not all(isinstance(value, int) and not isinstance(value, bool) for value in frames):
        raise StudyError(f"{where} capture frames must be [start, stop] or [start, stop, step] (integers), got {frames!r}")
    scale = table.get("scale", DEFAULT_SCALE)
    if scale != AUTO_SCALE and (not isinstance(scale, (int, float)) or isinstance(scale, bool) or not 0 < scale <= 1):
        raise StudyError(f"{where} capture scale must be a number in (0, 1] or {AUTO_SCALE!r}, got {scale!r}")
    reader = dict(_table(table.get("reader", {}), f"{where} capture reader"))
    try:
        if reader:  # an unknown or invalid option fails here, as run's --reader-set does
            capture_reader(capture, reader_options=reader)
        keypoints = keypoint_folder(capture, paths["keypoints"])
        joints = joints_file(capture, paths["joints"], reader.get("trial"))
        first = start_with_joints(joints, frames[0] if frames else None, f"frames {frames}", lambda first: f"start the frames at {first}")
    except InputError as error:
        raise StudyError(f"{where} capture: {error}") from error
    if first is not None:
        frames = [first, None]
    # Metres by default, not run's auto: the units are part of every cell's key, so a study made before auto keeps its cells.
    units = table.get("units", "m")
    if units not in UNIT_CHOICES:
        raise StudyError(f"{where} capture units must be one of {', '.join(UNIT_CHOICES)}, got {units!r}")
    return {"path": str(capture), "calibration": paths["calibration"], "units": units, "scale": scale if scale == AUTO_SCALE else float(scale),
            "frames": list(frames), "cameras": list(_strings(table.get("cameras", []), f"{where} capture cameras")),
            "holdout": list(_strings(table.get("holdout", []), f"{where} capture holdout")),
            "keypoints": str(keypoints) if keypoints else None, "joints": str(joints) if joints else None,
            # absent unless given, so that the cells of studies made before keep their keys
            **({"reader": reader} if reader else {})}


def _segmenter(value: Any, where: str) -> PluginChoice:
    if isinstance(value, str):
        return PluginChoice("segmenter", value)
    if isinstance(value, Mapping) and isinstance(value.get("name"), str):
        return PluginChoice("segmenter", value["name"], {k: v for k, v in value.items() if k != "name"})
    raise StudyError(f"{where} segmenter must be a name or a table with a string 'name'")


def _variants(row: Mapping[str, Any], index: int, shared: Mapping[str, Any], source: str, folder: Path | None) -> list[Variant]:
    """The variants of one ``[[variant]]`` table: one, or one per point of its grid."""
    where = f"{source}: [[variant]] #{index + 1}"
    _check_keys(row, VARIANT_KEYS, source, f"[[variant]] #{index + 1}")
    name = row.get("name")
    if not isinstance(name, str) or not name:
        raise StudyError(f"{where} needs a string 'name'")
    where = f"{source}: variant {name!r}"
    base = row.get("config")
    if not isinstance(base, str) or not base:
        raise StudyError(f"{where} needs 'config': a built-in configuration name or a TOML file")
    is_file = base.endswith(".toml") or "/" in base
    try:
        config = load_config(_resolve_path(base, folder, f"{where} config") if is_file else base)
    except ConfigError as error:
        raise StudyError(f"{where}: {error}") from error
    values: Mapping[str, Any] = config.values
    for kind in VARIANT_PLUGIN_TABLES:
        if kind in row:
            values = {**values, kind: row[kind]}
    overrides = {**shared, **flatten(_table(row.get("set", {}), f"{where} set"))}
    grid = flatten(_table(row.get("grid", {}), f"{where} grid"))
    for key, choices in grid.items():
        if not isinstance(choices, list) or not choices:
            raise StudyError(f"{where} grid: {key!r} must be a non-empty list of values")
    segmenter = _segmenter(row["segmenter"], where) if "segmenter" in row else None
    labels = _grid_labels(list(grid))
    variants = []
    for point in itertools.product(*grid.values()):
        chosen = dict(zip(grid, point))
        resolved = values
        suffix = ", ".join(f"{labels[key]}={value}" for key, value in chosen.items())
        try:
            for key, value in {**overrides, **chosen}.items():
                resolved = set_value(resolved, key, value, where)
            variants.append(Variant(f"{name} ({suffix})" if suffix else name, Config(f"{where} ({config.source})", resolved), segmenter))
        except ConfigError as error:
            raise StudyError(str(error)) from error
    return variants


def _grid_labels(keys: Sequence[str]) -> dict[str, str]:
    """Short labels of grid keys for variant names: the last part, unless two keys share it."""
    last = [key.rsplit(".", 1)[-1] for key in keys]
    return {key: short if last.count(short) == 1 else key for key, short in zip(keys, last)}


def flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Dotted keys of a nested table (``{fit = {iterations = 5}}`` → ``{"fit.iterations": 5}``); a key
    written quoted with dots (``"fit.iterations" = 5``) is already dotted."""
    flat: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, f"{dotted}."))
        else:
            flat[dotted] = value
    return flat


def _validate(study: Study, registry: Registry) -> None:
    """Fail before anything runs: unknown plugins or parameters, malformed plugin tables, unknown ``[fit]`` keys."""
    from mmcsplat.training.settings import FitSettings

    try:
        for backend in study.backends:
            registry.get("renderer", backend)
        for segmenter in [s.segmenter for s in study.sessions] + [v.segmenter for v in study.variants]:
            if segmenter is not None:
                registry.check_parameters("segmenter", segmenter.name, segmenter.params)
    except (PluginError, InputError) as error:
        raise StudyError(f"{study.source}: {error}") from error
    for variant in study.variants:
        try:
            variant.config.plugin("renderer")
            if len(variant.config.plugins("dynamics")) > 1:
                raise ConfigError(f"{variant.config.source}: at most one [dynamics] table")
            for kind in VARIANT_PLUGIN_TABLES:
                for choice in variant.config.plugins(kind):
                    registry.check_parameters(kind, choice.name, choice.params)  # a misspelt key before anything runs
            FitSettings.from_config(variant.config)
        except (ConfigError, PluginError, TypeError, ValueError) as error:
            raise StudyError(f"{study.source}: variant {variant.name!r}: {error}") from error
    for spec in study.sessions:  # before anything runs, not as cells' failures kept after the session appears
        if spec.path is not None and "://" not in spec.path and not Path(spec.path).is_dir():
            raise StudyError(f"{study.source}: [sessions.{spec.name}] path: no session at {spec.path} (`mmcsplat ingest` makes one)")
        _check_camera_names(study, spec)


def _check_camera_names(study: Study, spec: SessionSpec) -> None:
    """The cameras a synthetic or stored session is told to keep, perturb, hold out or fold over are among its
    own, checked when the study loads, so ``--dry-run`` lists no cell the run would refuse. A capture's cameras
    are known only once it is ingested (the runner checks its folds then)."""
    from mmcsplat.storage.session import SessionReader
    from mmcsplat.synthetic.cameras import camera_names

    if spec.synthetic is not None:
        names = camera_names(int(spec.synthetic["cameras"]))
    elif spec.path is not None and "://" not in spec.path:
        try:
            names = SessionReader(spec.path).camera_names
        except (OSError, InputError) as error:
            raise StudyError(f"{study.source}: [sessions.{spec.name}] path: {error}") from error
    else:
        return
    kept = spec.cameras if spec.cameras is not None else names
    named = [("cameras", kept), ("heldout", spec.heldout), ("perturb", [spec.perturb.camera] if spec.perturb else [])]
    named.append(("folds", spec.folds if spec.folds is not None else study.folds))
    for key, cameras in named:
        among = names if key in ("cameras", "heldout") else kept
        unknown = [camera for camera in cameras if camera not in among]
        if unknown:
            raise StudyError(f"{study.source}: [sessions.{spec.name}] {key}: no camera {unknown[0]!r} in the session"
                             + (" as its 'cameras' keep it" if among is not names else "") + f"; its cameras: {list(among)}")


# ----------------------------------------------------------------------------------------- expansion


def plan_sessions(study: Study, out: Path) -> dict[tuple[str, str], SessionPlan]:
    """The session each (session name, :func:`segmenter_key` of a variant's segmenter) reads: stored
    sessions in place, synthesized and segmented ones under ``out/sessions/NAME/``."""
    plans = {}
    for spec in study.sessions:
        for variant in study.variants:
            segmenter = variant.segmenter or spec.segmenter
            if spec.capture is not None:
                identity: dict[str, Any] = {"capture": {key: value for key, value in spec.capture.items() if key != "joints"}}
            else:
                identity = {"synthetic": dict(spec.synthetic), "heldout": list(spec.heldout)} if spec.synthetic else {"path": spec.path}
                identity.update(spec.modifications)
            if segmenter is not None:  # absent otherwise, so that studies made before keep their cells
                identity["segmenter"] = {"name": segmenter.name, "params": dict(segmenter.params)}
            url = spec.path  # a stored session as it is, read in place; every other one is made under OUT/sessions
            if spec.capture is not None or segmenter is not None or spec.modifications:
                digest = hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()[:8]
                stem = "capture" if spec.capture is not None else segmenter.name if segmenter else "copy"
                url = str(Path(out).resolve() / "sessions" / spec.name / f"{stem}-{digest}.zarr")
            plans[spec.name, segmenter_key(variant.segmenter)] = SessionPlan(spec, segmenter, str(url), identity)
    return plans


def segmenter_key(choice: PluginChoice | None) -> str:
    """A hashable stand-in for a segmenter choice (its parameters are a dict)."""
    return "" if choice is None else json.dumps([choice.name, dict(choice.params)], sort_keys=True, default=str)


def expand(study: Study, out: Path, registry: Registry | None = None) -> list[Cell]:
    """Every cell of the study, in order: sessions × variants × folds × seeds × backends."""
    from mmcsplat.pipeline.flow import DEFAULT_PRESET

    registry = registry or default_registry()
    plans = plan_sessions(study, out)
    flow = {variant.name: DEFAULT_PRESET if reads_flow(variant.config, registry) else None for variant in study.variants}
    cells = []
    for spec in study.sessions:
        folds: Sequence[str | None] = spec.folds if spec.folds is not None else study.folds
        for variant in study.variants:
            plan = plans[spec.name, segmenter_key(variant.segmenter)]
            for fold, seed, backend in itertools.product(folds or [None], study.seeds, study.backends or [None]):
                values = resolve(variant.config, seed, backend, registry)
                renderer = values["renderer"]["name"]
                cell_spec = CellSpec(variant.config.source, values, plan.url, plan.identity,
                                     (fold,) if fold is not None else None, seed, renderer, spec.ground_truth,
                                     spec.capture.get("joints") if spec.capture else None, flow[variant.name])
                cells.append(Cell(variant.name, spec.name, fold or "default", seed, renderer, cell_spec, plan))
    return cells


def reads_flow(config: Config, registry: Registry) -> bool:
    """Whether the dynamics method of ``config`` (if any), built with its parameters, reads the session's
    optical flow (:attr:`~mmcsplat.plugin_api.interfaces.Dynamics.reads_flow`); a method not usable here
    reads none (its cells fail, saying why)."""
    dynamics = config.plugins("dynamics")
    if not dynamics:
        return False
    try:
        return bool(registry.create("dynamics", dynamics[0].name, **dynamics[0].params).reads_flow)
    except PluginUnavailableError:
        return False
    except PluginError as error:
        raise StudyError(f"{config.source}: {error}") from error


def resolve(config: Config, seed: int, backend: str | None, registry: Registry) -> dict[str, Any]:
    """A variant's configuration for one seed and backend: ``fit.seed`` (and the dynamics method's
    ``seed`` when it takes one) set to ``seed``; the renderer replaced by ``backend`` (its parameters
    belong to the renderer they were written for)."""
    values = set_value(config.values, "fit.seed", seed, config.source)
    dynamics = config.plugins("dynamics")
    if dynamics and "seed" in accepted_parameters("dynamics", dynamics[0].name, registry):
        values = set_value(values, "dynamics.seed", seed, config.source)
    if backend is not None and backend != config.plugin("renderer").name:
        values["renderer"] = {"name": backend}
    return values


def accepted_parameters(kind: str, name: str, registry: Registry) -> dict[str, Any]:
    """The named parameters of a plugin's factory and their defaults (``inspect.Parameter.empty`` when
    it has none)."""
    factory = registry.get(kind, name).load()
    try:
        parameters = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):  # builtins without a signature
        return {}
    return {p.name: p.default for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


# ------------------------------------------------------------------------------------------- helpers


def _check_keys(table: Mapping[str, Any], known: Iterable[str], source: str, where: str) -> None:
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise StudyError(f"{source}: unknown {where} key(s) {unknown}; known: {sorted(known)}")


def _table(value: Any, where: str, required: bool = False) -> Mapping[str, Any]:
    if value is None and required:
        raise StudyError(f"{where} is missing")
    if not isinstance(value, Mapping):
        raise StudyError(f"{where} must be a table")
    return value


def _strings(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(item, str) and item for item in value):
        raise StudyError(f"{where} must be a list of names, got {value!r}")
    if len(set(value)) != len(value):
        raise StudyError(f"{where} repeats a name: {value}")
    return tuple(value)


def _integers(value: Any, where: str) -> tuple[int, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(item, int) and not isinstance(item, bool) for item in value):
        raise StudyError(f"{where} must be a non-empty list of integers, got {value!r}")
    if len(set(value)) != len(value):
        raise StudyError(f"{where} repeats a seed: {value}")
    return tuple(value)


def _resolve_path(value: Any, folder: Path | None, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise StudyError(f"{where} must be a non-empty string")
    path = Path(value).expanduser()
    if not path.is_absolute():
        if folder is None:
            raise StudyError(f"{where}: a built-in study cannot name the relative path {value!r}")
        path = folder / path
    return os.path.normpath(path)
