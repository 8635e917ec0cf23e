"""2D keypoints from SLEAP, one file per camera (anipose's layout), triangulated in the session's cameras.

Files, read with h5py (``*.analysis.h5`` when the folder has any, else ``*.slp``), matched to the
session's cameras by name (without ``.analysis.h5`` / ``.slp``) like videos, or by ``camera_map``:

- ``.analysis.h5`` (SLEAP's analysis export): datasets stored column-major for MATLAB, so h5py reads them
  transposed: ``tracks`` [tracks, 2, nodes, frames] (x, y; NaN where absent), ``point_scores`` [tracks,
  nodes, frames] (optional), ``track_occupancy`` [frames, tracks] and ``node_names``. Row k is frame k of
  the video (SLEAP exports from frame 0).
- ``.slp`` (SLEAP's labels file, an HDF5 file): the ``metadata`` group's ``json`` attribute holds the
  skeleton (its ``nodes`` list gives the node names; one skeleton only), ``frames`` the labelled frames
  (``frame_idx``, ``instance_id_start``, ``instance_id_end``; one video only), ``instances`` their
  instances (``instance_type`` 0 user-labelled, 1 predicted; ``track``; ``point_id_start``,
  ``point_id_end``), and ``points`` / ``pred_points`` their points (``x``, ``y``, ``visible``, and
  ``score`` for predictions). Per frame and track a user-labelled instance is taken over a prediction
  (hand-checked labels win); of untracked instances, the user-labelled ones where there are any, else the
  predictions. Confidence: 1 for a visible
  user-labelled point, the score for a predicted one, 0 where not visible. Files older than format 1.1
  put pixel centres at +0.5: their points are shifted by −0.5 to mmcsplat's (and OpenCV's) integer
  centres.

Several animals (tracks, or untracked instances): the subject is the animal the cameras agree on
(:mod:`.keypoint_tables`), since a track's number in one camera's file need not be the same animal in
another's; ``track`` reads one track alone, for files tracked consistently across cameras.

The skeleton's edges (for masks drawn from the keypoints, ``segmenters/keypoints.py``): an analysis
file's ``edge_names`` [edges, 2] (source, destination node names); a labels file's skeleton ``links``
(``source`` and ``target`` index the ``nodes`` list; only body edges, type 1, not symmetries).
Files are found in ``folder`` or named one per camera by ``files``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.parameters import between, parameter

from .keypoint_tables import KeypointTable, TableKeypoints

ANALYSIS_SUFFIX = ".analysis.h5"
LABELS_SUFFIX = ".slp"
#: The .slp format version from which pixel centres are at integer coordinates.
CENTRED_FORMAT = 1.1
USER, PREDICTED = 0, 1
#: SLEAP's type of a body edge (2 marks a symmetry: a left and right pair, not a link of the body).
BODY_EDGE = 1


def _names(raw: np.ndarray) -> tuple[str, ...]:
    return tuple(name.decode() if isinstance(name, bytes) else str(name) for name in np.asarray(raw).ravel())


def read_sleap_analysis(path: Path, track: int | None = None) -> KeypointTable:
    """(node names, frame numbers [T], [T, P, L, 3] x, y, score) of every track (P) in a SLEAP analysis HDF5
    file, or of ``track`` alone."""
    import h5py

    try:
        with h5py.File(path, "r") as file:
            missing = [key for key in ("tracks", "node_names") if key not in file]
            if missing:
                raise InputError(f"{path}: not a SLEAP analysis file (no {', '.join(missing)})")
            tracks = np.asarray(file["tracks"][()], dtype=np.float64)
            names = _names(file["node_names"][()])
            scores = np.asarray(file["point_scores"][()], dtype=np.float64) if "point_scores" in file else None
    except OSError as error:
        raise InputError(f"{path}: not a readable HDF5 file ({error})") from None
    if tracks.ndim != 4 or tracks.shape[1] != 2 or tracks.shape[2] != len(names):
        raise InputError(f"{path}: 'tracks' has shape {tracks.shape}, expected [tracks, 2, {len(names)} nodes, frames] as SLEAP writes it")
    if track is not None and not 0 <= track < tracks.shape[0]:
        raise InputError(f"{path}: no track {track} (the file has {tracks.shape[0]}); choose one with track=N")
    chosen = slice(None) if track is None else slice(track, track + 1)
    xy = tracks[chosen].transpose(3, 0, 2, 1)  # [frames, tracks, nodes, 2]
    scored = scores is not None and scores.shape == (tracks.shape[0], len(names), tracks.shape[3])
    score = scores[chosen].transpose(2, 0, 1) if scored else np.ones(xy.shape[:3])
    score = np.where(np.all(np.isfinite(xy), axis=-1), np.nan_to_num(score, nan=1.0), np.nan)
    return names, np.arange(xy.shape[0]), np.concatenate([xy, score[..., None]], axis=-1)


def read_sleap_labels(path: Path, track: int | None = None) -> KeypointTable:
    """(node names, labelled frame numbers, [T, P, L, 3] x, y, confidence of every animal, or of ``track``
    alone) of a SLEAP ``.slp`` file."""
    import h5py

    try:
        with h5py.File(path, "r") as file:
            missing = [key for key in ("metadata", "frames", "instances", "points", "pred_points") if key not in file]
            if missing:
                raise InputError(f"{path}: not a SLEAP labels file (no {', '.join(missing)})")
            metadata = json.loads(_text(file["metadata"].attrs["json"]))
            version = float(file["metadata"].attrs.get("format_id", CENTRED_FORMAT))
            frames, instances = file["frames"][()], file["instances"][()]
            points, predicted = file["points"][()], file["pred_points"][()]
    except (OSError, KeyError, ValueError) as error:
        raise InputError(f"{path}: not a readable SLEAP labels file ({error})") from None
    if len(metadata.get("skeletons", [])) > 1:
        raise InputError(f"{path}: {len(metadata['skeletons'])} skeletons; mmcsplat reads files of one skeleton")
    names = tuple(node["name"] for node in metadata.get("nodes", []))
    if not names:
        raise InputError(f"{path}: its metadata names no skeleton nodes")
    if len(np.unique(frames["video"])) > 1:
        raise InputError(f"{path}: labels of several videos; export one .slp (or .analysis.h5) per camera")
    offset = 0.5 if version < CENTRED_FORMAT else 0.0
    numbers, table = [], []
    for frame in frames:
        animals = []
        for chosen in _instances(instances[frame["instance_id_start"] : frame["instance_id_end"]], track):
            user = chosen["instance_type"] == USER
            rows = (points if user else predicted)[chosen["point_id_start"] : chosen["point_id_end"]]
            if len(rows) != len(names):
                raise InputError(f"{path}: frame {frame['frame_idx']}: an instance of {len(rows)} points, but the skeleton has {len(names)} nodes")
            confidence = np.where(rows["visible"], 1.0 if user else rows["score"], np.nan)
            xy = np.where(rows["visible"][:, None], np.column_stack([rows["x"], rows["y"]]) - offset, np.nan)
            animals.append(np.column_stack([xy, confidence]))
        if animals:
            numbers.append(int(frame["frame_idx"]))
            table.append(animals)
    most = max((len(animals) for animals in table), default=1)
    padded = np.full((len(table), most, len(names), 3), np.nan)
    for k, animals in enumerate(table):
        padded[k, : len(animals)] = animals
    return names, np.asarray(numbers, dtype=np.int64), padded


def read_sleap_edges(path: Path) -> tuple[tuple[str, str], ...]:
    """The (source, destination) node names of the skeleton's body edges in a SLEAP file (none where it declares none)."""
    import h5py

    try:
        with h5py.File(path, "r") as file:
            if path.name.endswith(ANALYSIS_SUFFIX):
                pairs = np.asarray(file["edge_names"][()]) if "edge_names" in file else np.empty((0, 2))
                if pairs.ndim == 2 and pairs.shape[0] == 2 and pairs.shape[1] != 2:  # written transposed, for MATLAB
                    pairs = pairs.T
                return tuple((_text(a), _text(b)) for a, b in pairs.reshape(-1, 2))
            metadata = json.loads(_text(file["metadata"].attrs["json"]))
    except (OSError, KeyError, ValueError) as error:
        raise InputError(f"{path}: its skeleton cannot be read ({error})") from None
    names = [node["name"] for node in metadata.get("nodes", [])]
    skeletons = metadata.get("skeletons", [])
    try:
        return tuple((names[link["source"]], names[link["target"]]) for link in (skeletons[0].get("links", []) if skeletons else [])
                     if _edge_type(link.get("type", {})) == BODY_EDGE)
    except (IndexError, TypeError, KeyError) as error:
        raise InputError(f"{path}: a skeleton link does not name two of its {len(names)} nodes ({error})") from None


def _edge_type(value) -> int:
    """A link's type as SLEAP stores it: a pickled EdgeType (``py/reduce``, its value the tuple's first item), a
    reference ``py/id`` to an earlier one (whose number is the type's, as SLEAP writes the body type first), or absent (a body edge)."""
    if isinstance(value, dict) and "py/reduce" in value:
        return int(value["py/reduce"][1]["py/tuple"][0])
    if isinstance(value, dict) and "py/id" in value:
        return int(value["py/id"])
    return BODY_EDGE


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _instances(instances: np.ndarray, track: int | None) -> list:
    """A frame's instances to read: of ``track`` alone, its user-labelled instance if any, else its prediction
    (any instance where none is tracked); of every animal (``track`` None), that for each track, and of the
    untracked instances the user-labelled ones if any, else the predictions."""
    if track is not None:
        for kind in (USER, PREDICTED):
            candidates = instances[instances["instance_type"] == kind]
            tracked = candidates[candidates["track"] == track]
            if len(tracked):
                return [tracked[0]]
            if len(candidates) and np.all(candidates["track"] < 0):
                return [candidates[0]]
        return []
    chosen = []
    for number in np.unique(instances["track"][instances["track"] >= 0]):
        on_track = instances[instances["track"] == number]
        users = on_track[on_track["instance_type"] == USER]
        chosen.append(users[0] if len(users) else on_track[0])
    untracked = instances[instances["track"] < 0]
    users = untracked[untracked["instance_type"] == USER]
    return chosen + list(users if len(users) else untracked)


@attrs.frozen
class SleapKeypoints(TableKeypoints):
    """SLEAP keypoints (``.analysis.h5`` or ``.slp``) per camera, triangulated (module docstring)."""

    folder: str | None = parameter(None, doc="the folder of one SLEAP .analysis.h5 or .slp file per camera")
    files: tuple[str, ...] | None = parameter(None, doc="the SLEAP files themselves, one per camera (instead of folder)")
    min_confidence: float = parameter(0.3, doc="points of a lower score are not used (user-labelled visible points score 1)",
                                      validator=between(0, 1))
    track: int | None = parameter(None, doc="the track (animal) to read, where it is the same animal in every camera's file "
                                           "(default: the animal the cameras agree on)")

    SUFFIXES: ClassVar[tuple[str, ...]] = (ANALYSIS_SUFFIX, LABELS_SUFFIX)

    @property
    def described(self) -> str:
        return f"SLEAP keypoints {self.where}"

    def read_table(self, path: Path) -> KeypointTable:
        return read_sleap_analysis(path, self.track) if path.name.endswith(ANALYSIS_SUFFIX) else read_sleap_labels(path, self.track)

    def read_edges(self, path: Path) -> tuple[tuple[str, str], ...]:
        return read_sleap_edges(path)
