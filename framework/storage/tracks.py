"""Per-frame Gaussian states of a dynamic run: ``RUN/tracks.zarr``, written once by a dynamics method and
read by evaluation, rendering and export.

On-disk layout (format version 1)::

    RUN/tracks.zarr/                  a zarr v3 group
        zarr.json                     attributes: mmcsplat_tracks (1), complete (true, written last),
                                      num_frames T, num_gaussians N, method, static [names],
                                      dynamic [names], attrs {…the method's own metadata},
                                      recording (the session's fingerprint, stamped by ``track``
                                      once the tracks are complete; absent in older tracks),
                                      fit (the digest of the fit tracked from, stamped with it)
        <static name>    [N, ...]     parameters that do not change over time (e.g. opacity_logits)
        <dynamic name>   [T, N, ...]  float32, one frame per chunk (at least means and quats)

Every name of :data:`mmcsplat.scene.gaussian_table.GAUSSIAN_PARAMETERS` is either static or dynamic. Writes are atomic as
in the session store: the group is written in a hidden sibling directory and renamed into place by
:meth:`TrackWriter.commit`, which requires every frame to have been written.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError, MissingFileError, OutputExistsError
from mmcsplat.plugin_api.render_contract import Gaussians, gaussians_from_params
from mmcsplat.scene.gaussian_table import GAUSSIAN_PARAMETERS, PARAMETER_SHAPES
from mmcsplat.storage.atomic import remove_leftovers, remove_local_tree
from mmcsplat.storage.chunks import open_stored, read_stored
from mmcsplat.storage.run import TRACKS_DIR
from mmcsplat.storage.transaction import Transaction

FORMAT_VERSION = 1
#: Parameters every frame must carry.
REQUIRED_DYNAMIC = ("means", "quats")


def _as_float32(name: str, value: torch.Tensor | np.ndarray, count: int | None, where: str) -> np.ndarray:
    """``value`` as a float32 numpy array after checking it is [N, *PARAMETER_SHAPES[name]] and finite."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    array = np.asarray(value, dtype=np.float32)
    expected = (array.shape[0] if count is None and array.ndim else count, *PARAMETER_SHAPES[name])
    if array.shape != expected:
        raise InputError(f"{where}: {name} must have shape {list(expected)}, got {list(array.shape)}")
    if not np.isfinite(array).all():
        bad = int((~np.isfinite(array)).reshape(len(array), -1).any(axis=1).sum())
        raise InputError(f"{where}: {name} is non-finite in {bad} Gaussian(s)")
    return array


class TrackWriter(Transaction):
    """Writes ``RUN/tracks.zarr`` frame by frame; nothing reads as tracks before :meth:`commit`.

    ``static`` holds the per-Gaussian parameters that do not change over time; every other name of
    ``GAUSSIAN_PARAMETERS`` is dynamic and must be passed to each :meth:`write_frame` (means and quats are
    always dynamic). ``attrs`` is the method's JSON-serialisable metadata. A context manager: an exception
    in the ``with`` block aborts, a normal exit commits.
    """

    def __init__(
        self,
        run: Path,
        *,
        num_frames: int,
        static: Mapping[str, torch.Tensor | np.ndarray],
        method: str,
        attrs: dict[str, Any] | None = None,
        overwrite: bool = False,
    ) -> None:
        import zarr
        from zarr.codecs import ZstdCodec

        run = Path(run)
        self.target = run / TRACKS_DIR
        self.url = str(self.target)
        self._overwrite = overwrite
        if not run.is_dir():
            raise MissingFileError(f"run directory {run} does not exist")
        if self.target.exists() and not overwrite:
            raise OutputExistsError(f"{self.target} already exists (--overwrite replaces it)")
        if num_frames < 1:
            raise InputError(f"{self.target}: num_frames must be ≥ 1, got {num_frames}")
        unknown = sorted(set(static) - set(GAUSSIAN_PARAMETERS))
        if unknown:
            raise InputError(f"{self.target}: unknown static parameters {unknown}; parameters are {list(GAUSSIAN_PARAMETERS)}")
        fixed = [name for name in REQUIRED_DYNAMIC if name in static]
        if fixed:
            raise InputError(f"{self.target}: {fixed} change every frame and cannot be static")
        if not static:
            raise InputError(f"{self.target}: at least one static parameter is needed to know the Gaussian count")
        self.num_frames = int(num_frames)
        self.dynamic = tuple(name for name in GAUSSIAN_PARAMETERS if name not in static)
        self.static = tuple(name for name in GAUSSIAN_PARAMETERS if name in static)
        arrays = {name: _as_float32(name, static[name], None, f"{self.target} static") for name in self.static}
        counts = {name: len(array) for name, array in arrays.items()}
        if len(set(counts.values())) != 1:
            raise InputError(f"{self.target}: static parameters disagree on the Gaussian count: {counts}")
        self.num_gaussians = next(iter(counts.values()))
        remove_leftovers(run, f".{TRACKS_DIR}.partial-")  # of a killed writer: the caller holds the run's lock
        self._partial = run / f".{TRACKS_DIR}.partial-{uuid.uuid4().hex[:8]}"
        self._written = np.zeros(self.num_frames, dtype=bool)
        try:
            self._group = zarr.open_group(str(self._partial), mode="w-", zarr_format=3)
            self._group.attrs.update({
                "mmcsplat_tracks": FORMAT_VERSION,
                "num_frames": self.num_frames,
                "num_gaussians": self.num_gaussians,
                "method": method,
                "static": list(self.static),
                "dynamic": list(self.dynamic),
                "attrs": dict(attrs or {}),
            })
            for name, array in arrays.items():
                self._group.create_array(name, data=array, compressors=[ZstdCodec(level=1)], config={"write_empty_chunks": True})
            self._arrays = {}
            for name in self.dynamic:
                shape = (self.num_frames, self.num_gaussians, *PARAMETER_SHAPES[name])
                self._arrays[name] = self._group.create_array(
                    name, shape=shape, chunks=(1, *shape[1:]), dtype=np.float32, compressors=[ZstdCodec(level=1)],
                    chunk_key_encoding={"name": "default", "separator": "."}, config={"write_empty_chunks": True},
                )
        except BaseException:
            self.abort()
            raise

    def write_frame(self, t: int, **dynamic: torch.Tensor | np.ndarray) -> None:
        """Store frame ``t``'s dynamic parameters (exactly the names not given as static)."""
        self._check_open()
        if not isinstance(t, int | np.integer) or not 0 <= t < self.num_frames:
            raise IndexError(f"{self.target}: frame {t!r} is out of range [0, {self.num_frames})")
        if set(dynamic) != set(self.dynamic):
            raise InputError(f"{self.target}: frame {t} must give exactly {list(self.dynamic)}, got {sorted(dynamic)}")
        for name in self.dynamic:
            self._arrays[name][int(t)] = _as_float32(name, dynamic[name], self.num_gaussians, f"{self.target} frame {t}")
        self._written[int(t)] = True

    def commit(self) -> None:
        """Make the tracks visible (replacing existing ones when ``overwrite``); every frame must be written."""
        self._check_open()
        try:
            missing = np.flatnonzero(~self._written)
            if len(missing):
                shown = ", ".join(map(str, missing[:10])) + (" …" if len(missing) > 10 else "")
                raise InputError(f"{self.target}: {len(missing)} frame(s) were never written: {shown}")
            self._group.attrs["complete"] = True
            if self.target.exists():
                if not self._overwrite:
                    raise OutputExistsError(f"{self.target} appeared while the tracks were written (--overwrite replaces it)")
                replaced = self.target.parent / f".{TRACKS_DIR}.replaced-{uuid.uuid4().hex[:8]}"
                os.replace(self.target, replaced)
                os.replace(self._partial, self.target)
                remove_local_tree(replaced)
            else:
                os.replace(self._partial, self.target)
        except BaseException:
            self.abort()
            raise
        self._done = True

    def abort(self) -> None:
        """Remove everything written; the writer cannot be used afterwards."""
        if self._done:
            return
        self._done = True
        remove_local_tree(self._partial)


def tracks_token(run: Path) -> tuple[int, int] | None:
    """What identifies the tracks now in ``run`` (their metadata file's inode and time), ``None`` without
    tracks: unchanged across a dynamics method's ``track``, the method wrote nothing."""
    try:
        status = os.stat(Path(run) / TRACKS_DIR / "zarr.json")
    except OSError:
        return None
    return status.st_ino, status.st_mtime_ns


def stamp_recording(run: Path, fingerprint: str | None, fit: str) -> None:
    """Record in ``run``'s complete tracks the fingerprint of the recording they were tracked on and the
    digest of the fit they start from (one attribute write)."""
    import zarr

    zarr.open_group(str(Path(run) / TRACKS_DIR), mode="r+", zarr_format=3).attrs.update({"recording": fingerprint, "fit": fit})


class TrackReader:
    """The complete tracks of a run, read one frame at a time."""

    def __init__(self, run: Path) -> None:
        import zarr

        self.path = Path(run) / TRACKS_DIR
        if not self.path.is_dir():
            raise MissingFileError(f"no tracks at {self.path}: run `mmcsplat track {run}` first")
        self.url = str(self.path)
        damaged = f"{self.path}: the tracks' metadata is damaged"
        try:
            group = zarr.open_group(str(self.path), mode="r", zarr_format=3)
        except (ValueError, zarr.errors.GroupNotFoundError, zarr.errors.ContainsArrayError) as error:  # garbled or missing zarr.json
            raise InputError(f"{damaged} ({error}); track the run again with `mmcsplat track {run} --overwrite`") from error
        attributes = group.attrs.asdict()
        version = attributes.get("mmcsplat_tracks")
        if version is None:
            raise InputError(f"{self.path} is a zarr group but not mmcsplat tracks")
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise InputError(f"{self.path}: tracks format {version} is newer than this mmcsplat reads ({FORMAT_VERSION})")
        if attributes.get("complete") is not True:
            raise InputError(f"{self.path}: the tracks were never completed")
        try:
            self.num_frames: int = int(attributes["num_frames"])
            self.num_gaussians: int = int(attributes["num_gaussians"])
            self.method: str = str(attributes["method"])
            self.attrs: dict[str, Any] = dict(attributes["attrs"])
            self.static: tuple[str, ...] = tuple(attributes["static"])
            self.dynamic: tuple[str, ...] = tuple(attributes["dynamic"])
        except (KeyError, TypeError, ValueError) as error:
            raise InputError(f"{damaged} (attribute {error}); track the run again with `mmcsplat track {run} --overwrite`") from error
        self._fingerprint = attributes.get("recording")
        self.fit: str | None = attributes.get("fit")  # the digest of the fit tracked from (None: tracks older than it)
        self._static = {name: torch.from_numpy(read_stored(open_stored(group, name, str(self.path)), None, f"{self.path}: static {name}"))
                        for name in self.static}
        self._arrays = {name: open_stored(group, name, str(self.path)) for name in self.dynamic}
        shapes = {name: array.shape[:2] for name, array in self._arrays.items()} | {name: value.shape[:1] for name, value in self._static.items()}
        expected = (self.num_frames, self.num_gaussians)
        wrong = {name: list(shape) for name, shape in shapes.items() if shape != (expected if name in self._arrays else expected[1:])}
        if wrong:
            raise InputError(f"{damaged}: it says {self.num_frames} frames of {self.num_gaussians} Gaussians, but the arrays hold {wrong}; "
                             f"track the run again with `mmcsplat track {run} --overwrite`")

    @property
    def fingerprint(self) -> str | None:
        """The fingerprint of the recording the tracks were made from (``None``: tracks older than it)."""
        return self._fingerprint

    def _check(self, t: int) -> int:
        if not isinstance(t, int | np.integer) or not 0 <= t < self.num_frames:
            raise IndexError(f"{self.path}: frame {t!r} is out of range [0, {self.num_frames})")
        return int(t)

    def params(self, t: int) -> dict[str, torch.Tensor]:
        """Every parameter of ``GAUSSIAN_PARAMETERS`` at frame ``t`` (float32 tensors, static ones shared)."""
        t = self._check(t)
        dynamic = {name: torch.from_numpy(read_stored(array, t, f"{self.path}: {name}, frame {t}")) for name, array in self._arrays.items()}
        return {name: self._static[name] if name in self._static else dynamic[name] for name in GAUSSIAN_PARAMETERS}

    def gaussians(self, t: int) -> Gaussians:
        """The renderable Gaussians of frame ``t``."""
        return gaussians_from_params(self.params(t))

    def means(self, t: int) -> np.ndarray:
        """[N, 3] Gaussian centres at frame ``t``."""
        t = self._check(t)
        return read_stored(self._arrays["means"], t, f"{self.path}: means, frame {t}")
