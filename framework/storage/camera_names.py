"""Matching files (or folders) to calibrated cameras by name, for every reader of a rig's files: videos,
image folders, keypoint folders.

A file belongs to a calibrated camera when its stem equals the camera's name, or else when both have the
same *name key*: the lower-cased runs of letters and of digits, with digit runs compared as numbers and
every other character ignored (so ``cam_01`` ↔ ``cam01.mp4`` ↔ ``Cam-1.avi``), or else when the file's key
runs inside the camera's (Pose2Sim names ``cam01.mp4``'s camera ``int_cam01_img``). Two files with the
same key are ambiguous and an error; an explicit map overrides the rule. Last, a camera's key running
inside a file's (``cam1`` ↔ ``trial-cam1.csv``, as anipose and DeepLabCut name their files) matches, and a
camera named by letters matches a file whose name ends in ``cam`` and them (``A`` ↔ ``vid01-camA.avi``: anipose's
default ``cam_regex``, ``-cam([A-Z])$``).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from mmcsplat.plugin_api.errors import InputError, MissingFileError


def natural_key(text: str) -> tuple:
    """A sort key that orders digit runs as numbers (``frame2`` before ``frame10``)."""
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part) for part in re.findall(r"\d+|\D+", text.lower()))


def name_key(name: str) -> tuple:
    """The fuzzy identity of a camera name: letter runs and digit runs (as numbers), separators ignored."""
    return tuple(int(part) if part.isdigit() else part for part in re.findall(r"[a-z]+|\d+", name.lower()))


def _within(outer: tuple, inner: tuple) -> bool:
    """Whether the name key ``inner`` (which must hold a number) runs contiguously inside ``outer``."""
    if not any(isinstance(part, int) for part in inner):
        return False
    return any(outer[i : i + len(inner)] == inner for i in range(len(outer) - len(inner) + 1))


#: The ``camera_map`` value that pairs the calibration's cameras, in its order, with the files in name order.
BY_ORDER = "order"
#: Where a reader's ``camera_map`` (and ``trial``) is set (videos, image and mask folders), for the errors' hints.
READER_CAMERA_MAP = "the reader's camera_map: mmcsplat ingest --set, mmcsplat run --reader-set"
#: Where a keypoint source's ``camera_map`` (and ``trial``) is set, for the errors' hints.
KEYPOINTS_CAMERA_MAP = "the keypoint source's camera_map: mmcsplat run --keypoints-set, mmcsplat landmarks --set or --keypoints-set"


def match_cameras(names: Sequence[str], paths: Iterable[Path], what: str, where: Path,
                  camera_map: Mapping[str, str] | str | None = None, set_by: str = READER_CAMERA_MAP,
                  trial: str | None = None) -> dict[str, Path]:
    """Camera name → its file, for the cameras ``names``: by ``camera_map`` (calibration name → file
    stem) where given, else by the module's name rules, in their order; an error naming any camera without one, or with several. Files that match no camera are ignored with a warning. ``camera_map`` :data:`BY_ORDER` pairs the
    cameras, in the calibration's order, with the files in natural name order, when their counts agree.
    ``trial`` keeps only the files whose name starts with it (one recording of several side by side, as
    anipose keeps ``vid01-camA.avi`` beside ``vid02-camA.avi``; :func:`in_trial`). ``set_by`` says in the errors where
    ``camera_map`` and ``trial`` are set for these files.
    """
    paths = list(paths)
    if trial is not None:
        found = sorted({_label(path) for path in paths}, key=natural_key)
        paths = [path for path in paths if in_trial(_label(path), trial)]
        if not paths:
            raise MissingFileError(f"{where}: no {what} of trial {trial!r} (no name starts with it; found: {', '.join(found) or 'none'})")
    if isinstance(camera_map, str):
        if camera_map != BY_ORDER:
            raise InputError(f"{where}: camera_map must be a table (calibration name = file name) or {BY_ORDER!r}, got {camera_map!r}")
        ordered = sorted(paths, key=lambda path: natural_key(path.name))
        if len(ordered) != len(names):
            raise InputError(f"{where}: camera_map = {BY_ORDER!r} pairs cameras and {what}s in order, but the calibration has "
                             f"{len(names)} cameras and there are {len(ordered)} {what}s ({', '.join(p.name for p in ordered) or 'none'})")
        return dict(zip(names, ordered, strict=True))
    by_stem: dict[str, Path] = {}
    by_key: dict[tuple, list[Path]] = {}
    for path in paths:
        label = _label(path)
        by_stem[label] = path
        by_key.setdefault(name_key(label), []).append(path)
    unknown = sorted(set(camera_map or {}) - set(names))
    if unknown:
        raise InputError(f"{where}: camera_map names {', '.join(map(repr, unknown))}, not calibrated cameras ({', '.join(names)})")
    matched: dict[str, Path] = {}
    for name in names:
        if camera_map and name in camera_map:
            if camera_map[name] not in by_stem:
                raise MissingFileError(f"{where}: camera_map gives {camera_map[name]!r} for camera {name!r}, but no {what} "
                                       f"is called so (found: {', '.join(sorted(by_stem, key=natural_key)) or 'none'})")
            matched[name] = by_stem[camera_map[name]]
            continue
        if name in by_stem:
            matched[name] = by_stem[name]
            continue
        candidates = by_key.get(name_key(name), [])
        if not candidates:
            candidates = [path for key, found in by_key.items() if _within(name_key(name), key) for path in found]
        if not candidates:  # the camera's name inside the file's: anipose's and DeepLabCut's trial-cam1.mp4, …-cam1.csv
            candidates = [path for key, found in by_key.items() if _within(key, name_key(name)) for path in found]
        if not candidates and name.isalpha():  # anipose's default cam_regex, -cam([A-Z])$: camera A's files end in camA
            candidates = [path for key, found in by_key.items() if key and key[-1] == f"cam{name.lower()}" for path in found]
        if len(candidates) > 1:
            listed = ", ".join(sorted(path.name for path in candidates))
            raise InputError(f"{where}: camera {name!r} matches several {what}s ({listed}); choose one with "
                             f"camera_map={{{name}=\"FILE_STEM\"}}, or every camera's with trial=\"NAME_START\" ({set_by})")
        if not candidates:
            available = ", ".join(sorted(by_stem, key=natural_key)) or "none"
            raise MissingFileError(f"{where}: no {what} for calibrated camera {name!r} (found: {available}); map names with "
                                   f"camera_map={{{name}=\"FILE_STEM\"}} ({set_by})")
        matched[name] = candidates[0]
    owners: dict[Path, list[str]] = {}
    for name, path in matched.items():
        owners.setdefault(path, []).append(name)
    shared = {path: names for path, names in owners.items() if len(names) > 1}
    if shared:
        path, names = next(iter(shared.items()))
        raise InputError(f"{where}: cameras {', '.join(map(repr, names))} both match {path.name}; say which is which with camera_map ({set_by})")
    unused = sorted(set(by_stem.values()) - set(matched.values()))
    if unused:
        warnings.warn(f"{where}: ignoring {what}s of none of the cameras read ({', '.join(names)}): {', '.join(p.name for p in unused)}",
                      stacklevel=3)
    return matched


def in_trial(label: str, trial: str) -> bool:
    """Whether a file named ``label`` belongs to ``trial``: the name starts with it, and does not go on with
    the trial's last run of digits or letters (``vid1`` is not the start of ``vid10-camA``, ``vid`` is)."""
    if not label.startswith(trial):
        return False
    if not trial or len(label) == len(trial):
        return True
    last, following = trial[-1], label[len(trial)]
    return not ((last.isdigit() and following.isdigit()) or (last.isalpha() and following.isalpha()))


def _label(path: Path) -> str:
    """The name a file or folder is matched by: a file's stem, a folder's name."""
    return path.stem if path.is_file() else path.name
