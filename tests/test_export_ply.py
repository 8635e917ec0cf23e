"""mmcsplat export --ply: per-frame PLY files in the 3DGS viewers' layout, read back without a PLY library."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from render_fixtures import add_tracks, expected_means, fitted_run

from mmcsplat.cli import main
from mmcsplat.outputs.ply import PROPERTIES, SH_C0
from mmcsplat.pipeline.fit import load_fitted

FRAMES = 3


def read_ply(path):
    """(header lines, {property: [N] float32}) of a binary little-endian PLY with one float vertex element."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    count = int(header[2].split()[-1])
    names = [line.split()[2] for line in header if line.startswith("property")]
    assert all(line.startswith("property float ") for line in header if line.startswith("property"))
    vertices = np.frombuffer(data[end:], dtype=np.dtype([(name, "<f4") for name in names]))
    assert len(vertices) == count, "payload size disagrees with the header"
    return header, {name: vertices[name] for name in names}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(a tracked run, the same fit without tracks)."""
    root = tmp_path_factory.mktemp("export")
    run = fitted_run(root, iterations=1)
    static = root / "static"
    shutil.copytree(run, static)
    return add_tracks(run, FRAMES), static


def test_ply_round_trip(runs, tmp_path):
    out = tmp_path / "ply"
    assert main(["export", str(runs[0]), "--ply", str(out), "--no-progress"]) == 0
    assert sorted(path.name for path in out.iterdir()) == [f"frame_{t:04d}.ply" for t in range(FRAMES)]
    _, params, _, _ = load_fitted(runs[0])
    for t in range(FRAMES):
        header, vertices = read_ply(out / f"frame_{t:04d}.ply")
        assert tuple(vertices) == PROPERTIES and header[2] == f"element vertex {len(params['means'])}"
        np.testing.assert_allclose(np.stack([vertices[k] for k in "xyz"], 1), expected_means(runs[0], t), atol=1e-6)
    colour = torch.sigmoid(params["color_logits"]).numpy()
    np.testing.assert_allclose(np.stack([vertices[f"f_dc_{i}"] for i in range(3)], 1) * SH_C0 + 0.5, colour, atol=1e-6)
    np.testing.assert_allclose(vertices["opacity"], params["opacity_logits"].numpy(), atol=1e-6)
    np.testing.assert_allclose(np.stack([vertices[f"scale_{i}"] for i in range(3)], 1), params["log_scales"].numpy(), atol=1e-6)
    quats = params["quats"].numpy() / np.linalg.norm(params["quats"].numpy(), axis=1, keepdims=True)
    np.testing.assert_allclose(np.stack([vertices[f"rot_{i}"] for i in range(4)], 1), quats, atol=1e-6)
    assert not np.any([vertices[f"n{axis}"] for axis in "xyz"])


def test_a_run_without_tracks_exports_its_first_frame(runs, tmp_path):
    assert main(["export", str(runs[1]), "--ply", str(tmp_path), "--no-progress"]) == 0
    assert [path.name for path in tmp_path.iterdir()] == ["frame_0000.ply"]
    _, params, _, _ = load_fitted(runs[1])
    _, vertices = read_ply(tmp_path / "frame_0000.ply")
    np.testing.assert_allclose(vertices["x"], params["means"][:, 0].numpy(), atol=1e-6)


def test_export_of_a_directory_that_is_no_run_fails_clearly(tmp_path, capsys):
    assert main(["export", str(tmp_path / "missing"), "--ply", str(tmp_path / "out")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
