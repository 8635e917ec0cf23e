"""Gaussians as PLY files in the layout 3DGS viewers read (``mmcsplat export --ply``, ``--inria``).

One binary little-endian vertex element per file, one vertex per Gaussian, float32 properties in this
order: ``x y z`` (metres), ``nx ny nz`` (zero, unused), ``f_dc_0..2`` (degree-0 spherical harmonics:
(colour − 0.5) / C0, viewers add 0.5 back after multiplying by C0), then for a spherical-harmonics degree
d > 0 the higher coefficients ``f_rest_0..M-1`` (M = 3·((d + 1)² − 1), channel-major: ``f_rest_{c·K + j}``
is coefficient j of channel c with K = M / 3; all zero, the fit has view-independent colour), then
``opacity`` (logit), ``scale_0..2`` (log), ``rot_0..3`` (unit quaternion w, x, y, z).

Degree 0 (the default, :data:`PROPERTIES`) is the compact layout most viewers read; degree 3
(:data:`FULL_PROPERTIES`, 45 ``f_rest``) is the reference 3DGS trainer's own, which its SIBR viewer and the
tools built on that layout require.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from mmcsplat.pipeline.run_frames import RunStates
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.atomic import atomic_path, replaced_folder

SH_C0 = 0.28209479177387814  # the degree-0 real spherical harmonic, 1 / (2 √π)
MAX_SH_DEGREE = 3
FULL_SH_DEGREE = 3  # the reference 3DGS layout


def properties(sh_degree: int = 0) -> tuple[str, ...]:
    """The vertex properties, in file order, of the layout with spherical harmonics up to ``sh_degree``."""
    if not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise InputError(f"PLY spherical-harmonics degree must be 0 to {MAX_SH_DEGREE}, got {sh_degree}")
    rest = tuple(f"f_rest_{i}" for i in range(3 * ((sh_degree + 1) ** 2 - 1)))
    return ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", *rest, "opacity",
            "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


PROPERTIES = properties(0)
FULL_PROPERTIES = properties(FULL_SH_DEGREE)


def ply_vertices(params: Mapping[str, torch.Tensor], sh_degree: int = 0) -> np.ndarray:
    """The structured [N] array (float32 fields named by :func:`properties` of ``sh_degree``) of
    ``GAUSSIAN_PARAMETERS`` tensors."""
    names = properties(sh_degree)
    quats = params["quats"].detach().double()
    means = params["means"].detach().double()
    columns = torch.cat([
        means,
        torch.zeros_like(means),
        (torch.sigmoid(params["color_logits"].detach().double()) - 0.5) / SH_C0,
        means.new_zeros(len(means), len(names) - len(PROPERTIES)),  # f_rest: view-independent colour
        params["opacity_logits"].detach().double()[:, None],
        params["log_scales"].detach().double(),
        quats / quats.norm(dim=-1, keepdim=True),
    ], dim=1).numpy()
    vertices = np.empty(len(columns), dtype=np.dtype([(name, "<f4") for name in names]))
    for index, name in enumerate(names):
        vertices[name] = columns[:, index]
    return vertices


def write_ply(path: str | Path, params: Mapping[str, torch.Tensor], sh_degree: int = 0, comments: Sequence[str] = ()) -> None:
    """Write the Gaussians ``params`` as a binary PLY at ``path``, atomically, in the layout of
    ``sh_degree`` (0: compact; :data:`FULL_SH_DEGREE`: the reference 3DGS layout), with header ``comments``
    (one line each)."""
    vertices = ply_vertices(params, sh_degree)
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {' '.join(comment.split())}" for comment in comments),
              f"element vertex {len(vertices)}"]
    header += [f"property float {name}" for name in vertices.dtype.names]
    header.append("end_header\n")
    with atomic_path(path) as temporary, open(temporary, "wb") as handle:
        handle.write("\n".join(header).encode("ascii"))
        handle.write(vertices.tobytes())


def _exported_frame(path: Path) -> bool:
    """Whether ``path`` is a frame an earlier PLY export wrote: a ``frame_NNNN.ply`` file that is a PLY."""
    if not (path.is_file() and re.fullmatch(r"frame_\d{4,}\.ply", path.name)):
        return False
    with open(path, "rb") as handle:
        return handle.read(4) == b"ply\n"


def export_ply(run: str | Path, out: str | Path, progress: bool = True, sh_degree: int = 0, comments: Sequence[str] = ()) -> list[Path]:
    """One PLY per frame of ``run`` (its tracks, or the first-frame fit) in ``out``, named
    ``frame_NNNN.ply`` by session frame number, in the layout of ``sh_degree`` with header ``comments``;
    returns the paths. The files are written beside ``out``, which replaces ``out`` once all are whole; ``out``
    may hold only an earlier export's frames (anything else is refused, naming it)."""
    from tqdm import tqdm

    properties(sh_degree)  # a bad degree fails before the run is read
    states = RunStates(run)
    out = Path(out)
    names = [f"frame_{states.first_frame + k:04d}.ply" for k in range(states.num_frames)]
    with replaced_folder(out, _exported_frame) as staging:
        for k in tqdm(range(states.num_frames), desc="export ply", unit="frame", disable=not progress):
            write_ply(staging / names[k], states.params(k), sh_degree, comments)
    return [out / name for name in names]
