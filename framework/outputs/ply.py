"""Gaussians as PLY files in the layout 3DGS viewers read (``mmcsplat export --ply``).

One binary little-endian vertex element per file, one vertex per Gaussian, float32 properties in this
order: ``x y z`` (metres), ``nx ny nz`` (zero, unused), ``f_dc_0..2`` (degree-0 spherical harmonics:
(colour − 0.5) / C0, viewers add 0.5 back after multiplying by C0), ``opacity`` (logit), ``scale_0..2``
(log), ``rot_0..3`` (unit quaternion w, x, y, z).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from mmcsplat.outputs.run_frames import RunStates
from mmcsplat.storage.atomic import atomic_path

SH_C0 = 0.28209479177387814  # the degree-0 real spherical harmonic, 1 / (2 √π)
PROPERTIES = (
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
    "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
)
VERTEX = np.dtype([(name, "<f4") for name in PROPERTIES])


def ply_vertices(params: Mapping[str, torch.Tensor]) -> np.ndarray:
    """The structured [N] :data:`VERTEX` array of ``GAUSSIAN_PARAMETERS`` tensors."""
    quats = params["quats"].detach().double()
    columns = torch.cat([
        params["means"].detach().double(),
        torch.zeros_like(params["means"], dtype=torch.float64),
        (torch.sigmoid(params["color_logits"].detach().double()) - 0.5) / SH_C0,
        params["opacity_logits"].detach().double()[:, None],
        params["log_scales"].detach().double(),
        quats / quats.norm(dim=-1, keepdim=True),
    ], dim=1).numpy()
    vertices = np.empty(len(columns), dtype=VERTEX)
    for index, name in enumerate(PROPERTIES):
        vertices[name] = columns[:, index]
    return vertices


def write_ply(path: str | Path, params: Mapping[str, torch.Tensor]) -> None:
    """Write the Gaussians ``params`` as a binary PLY at ``path``, atomically."""
    vertices = ply_vertices(params)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}"]
    header += [f"property float {name}" for name in PROPERTIES]
    header.append("end_header\n")
    with atomic_path(path) as temporary, open(temporary, "wb") as handle:
        handle.write("\n".join(header).encode("ascii"))
        handle.write(vertices.tobytes())


def export_ply(run: str | Path, out: str | Path, progress: bool = True) -> list[Path]:
    """One PLY per frame of ``run`` (its tracks, or the first-frame fit) in ``out``, named
    ``frame_NNNN.ply`` by session frame number; returns the paths."""
    from tqdm import tqdm

    states = RunStates(run)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in tqdm(range(states.num_frames), desc="export ply", unit="frame", disable=not progress):
        path = out / f"frame_{states.first_frame + k:04d}.ply"
        write_ply(path, states.params(k))
        paths.append(path)
    return paths
