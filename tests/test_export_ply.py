"""mmcsplat export: per-frame PLY files in the 3DGS viewers' layouts (the compact one read back without a PLY
library, both through plyfile), and the reference trainer's model folder (--inria)."""

from __future__ import annotations

import ast
import json
import re
import shutil

import numpy as np
import pytest
import torch
from plyfile import PlyData
from render_fixtures import add_tracks, expected_means, fitted_run

from mmcsplat.cli import main
from mmcsplat.outputs.ply import FULL_PROPERTIES, PROPERTIES, SH_C0
from mmcsplat.storage.run_info import RunInfo
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.fitted_run import FittedRun

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
    params = FittedRun.load(runs[0]).params
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
    params = FittedRun.load(runs[1]).params
    _, vertices = read_ply(tmp_path / "frame_0000.ply")
    np.testing.assert_allclose(vertices["x"], params["means"][:, 0].numpy(), atol=1e-6)


def test_a_ply_export_replaces_its_own_folder_whole_and_nothing_else(runs, tmp_path, capsys):
    """Exporting a shorter run into a longer one's folder leaves none of the longer one's frames; a folder holding
    anything an export did not write (notes, a file named like a frame that is no PLY) is refused, untouched."""
    out = tmp_path / "ply"
    assert main(["export", str(runs[0]), "--ply", str(out), "--no-progress"]) == 0
    assert main(["export", str(runs[1]), "--ply", str(out), "--no-progress"]) == 0
    assert [path.name for path in out.iterdir()] == ["frame_0000.ply"]
    for name, text in (("notes.txt", "mine"), ("frame_0003.ply", "mine too")):
        (out / name).write_text(text)
        capsys.readouterr()
        assert main(["export", str(runs[0]), "--ply", str(out), "--no-progress"]) == 2
        assert f"holds {name}, which no export of this kind wrote" in capsys.readouterr().err
        assert (out / name).read_text() == text and (out / "frame_0000.ply").is_file()
        (out / name).unlink()
    assert not [path for path in tmp_path.iterdir() if path.name.startswith(".")]  # no staging left beside it


def test_export_of_a_directory_that_is_no_run_fails_clearly(tmp_path, capsys):
    assert main(["export", str(tmp_path / "missing"), "--ply", str(tmp_path / "out")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------- through plyfile


def plyfile_vertices(path):
    """{property: [N] values} of ``path``'s vertex element read by plyfile, after checking it is its only
    element, binary little-endian, all float32."""
    data = PlyData.read(str(path))
    assert [element.name for element in data.elements] == ["vertex"] and not data.text and data.byte_order == "<"
    vertices = data["vertex"].data
    assert all(vertices.dtype[name] == np.dtype("<f4") for name in vertices.dtype.names)
    return {name: vertices[name] for name in vertices.dtype.names}


def check_vertices(vertices, params, means, full):
    """``vertices`` (read by plyfile) hold ``params`` at Gaussian centres ``means`` in the layout asked for."""
    assert tuple(vertices) == (FULL_PROPERTIES if full else PROPERTIES)
    assert len(FULL_PROPERTIES) == 62 and [name for name in FULL_PROPERTIES if name.startswith("f_rest_")] == [f"f_rest_{i}" for i in range(45)]
    np.testing.assert_allclose(np.stack([vertices[k] for k in "xyz"], 1), means, atol=1e-6)
    colour = torch.sigmoid(params["color_logits"]).numpy()
    np.testing.assert_allclose(np.stack([vertices[f"f_dc_{i}"] for i in range(3)], 1) * SH_C0 + 0.5, colour, atol=1e-6)
    np.testing.assert_allclose(vertices["opacity"], params["opacity_logits"].numpy(), atol=1e-6)
    np.testing.assert_allclose(np.stack([vertices[f"scale_{i}"] for i in range(3)], 1), params["log_scales"].numpy(), atol=1e-6)
    quats = params["quats"].numpy() / np.linalg.norm(params["quats"].numpy(), axis=1, keepdims=True)
    np.testing.assert_allclose(np.stack([vertices[f"rot_{i}"] for i in range(4)], 1), quats, atol=1e-6)
    assert not np.any([vertices[name] for name in vertices if name[0] == "n" or name.startswith("f_rest_")])


@pytest.mark.parametrize("full", [False, True], ids=["degree-0", "full-sh"])
def test_both_layouts_read_back_through_plyfile(runs, tmp_path, full):
    out = tmp_path / "ply"
    assert main(["export", str(runs[0]), "--ply", str(out), "--no-progress", *(["--full-sh"] if full else [])]) == 0
    params = FittedRun.load(runs[0]).params
    for t in range(FRAMES):
        check_vertices(plyfile_vertices(out / f"frame_{t:04d}.ply"), params, expected_means(runs[0], t), full)


# ------------------------------------------------------------------------------------------- --inria


def test_inria_model_folder(runs, tmp_path):
    out = tmp_path / "model"
    assert main(["export", str(runs[0]), "--inria", str(out), "--frame", "2"]) == 0
    info = RunInfo.read(runs[0])
    assert sorted(str(path.relative_to(out)) for path in out.rglob("*") if path.is_file()) == [
        "cameras.json", "cfg_args", f"point_cloud/iteration_{info.iterations}/point_cloud.ply"]
    assert not [path for path in tmp_path.iterdir() if path.name.startswith(".")], "the temporary folder is left behind"
    params = FittedRun.load(runs[0]).params
    check_vertices(plyfile_vertices(out / f"point_cloud/iteration_{info.iterations}/point_cloud.ply"), params, expected_means(runs[0], 2), True)

    text = (out / "cfg_args").read_text()
    call = ast.parse(text, mode="eval").body
    assert isinstance(call, ast.Call) and call.func.id == "Namespace" and not call.args
    fields = {keyword.arg: ast.literal_eval(keyword.value) for keyword in call.keywords}
    assert fields == {"sh_degree": 3, "source_path": info.session, "model_path": str(out.resolve()), "images": "images",
                      "resolution": -1, "white_background": False, "data_device": "cuda", "eval": False}
    assert re.fullmatch(r"Namespace\(sh_degree=3, .*\)", text)

    session = SessionReader(info.session)
    entries = json.loads((out / "cameras.json").read_text())
    assert len(entries) == len(session.cameras) == 5
    for index, (entry, camera) in enumerate(zip(entries, session.cameras, strict=True)):
        assert list(entry) == ["id", "img_name", "width", "height", "position", "rotation", "fy", "fx"]
        assert (entry["id"], entry["img_name"], entry["width"], entry["height"]) == (index, camera.name, camera.width, camera.height)
        rotation = np.array(entry["rotation"])
        np.testing.assert_allclose(entry["position"], camera.center, atol=1e-12)
        np.testing.assert_allclose(rotation @ [0, 0, 1], camera.R[2], atol=1e-12)  # the viewing direction in world
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
        ahead = camera.center + rotation @ [0, 0, 1]  # a point 1 m along the optical axis lands at depth 1
        np.testing.assert_allclose(camera.R @ ahead + camera.t, [0, 0, 1], atol=1e-9)
        assert (entry["fx"], entry["fy"]) == (camera.K[0, 0], camera.K[1, 1])


def test_inria_export_of_a_run_without_tracks_is_its_fit(runs, tmp_path):
    out = tmp_path / "model"
    out.mkdir()  # an empty directory is fine
    assert main(["export", str(runs[1]), "--inria", str(out)]) == 0
    params = FittedRun.load(runs[1]).params
    ply = next(out.glob("point_cloud/iteration_*/point_cloud.ply"))
    check_vertices(plyfile_vertices(ply), params, params["means"].numpy(), True)


@pytest.mark.parametrize(("arguments", "message"), [
    (["--inria", "{tmp}/full"], "already exists and is not an empty folder"),
    (["--inria", "{tmp}/new", "--frame", str(FRAMES)], f"run frame {FRAMES} does not exist"),
    ([], "choose at least one output"),
    (["--inria", "{tmp}/new", "--full-sh"], "--full-sh sets the layout of --ply files"),
    (["--ply", "{tmp}/new", "--frame", "0"], "--frame picks the run frame of --inria"),
])
def test_inria_export_errors_are_one_line(runs, tmp_path, capsys, arguments, message):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    assert main(["export", str(runs[0]), *(argument.format(tmp=tmp_path) for argument in arguments)]) == 2
    error = capsys.readouterr().err
    assert message in error and error.count("\n") == 1
    assert sorted(path.name for path in tmp_path.iterdir()) == ["full"] and (tmp_path / "full" / "keep.txt").read_text() == "mine"


def test_transforms_folder_holds_the_rig_and_the_fitted_frame(runs, tmp_path):
    import cv2

    out = tmp_path / "ns"
    assert main(["export", str(runs[1]), "--transforms", str(out)]) == 0
    info = RunInfo.read(runs[1])
    session = SessionReader(info.session)
    document = json.loads((out / "transforms.json").read_text())
    assert document["camera_model"] == "OPENCV" and len(document["frames"]) == len(session.camera_names)
    assert document["train_filenames"] == [f"images/{name}.png" for name in info.train_cameras]
    assert document["val_filenames"] == [f"images/{name}.png" for name in info.heldout_cameras]
    for name, entry in zip(session.camera_names, document["frames"], strict=True):
        camera = session.camera(name)
        c2w = np.array(entry["transform_matrix"]) @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL axes back to OpenCV's
        np.testing.assert_allclose(c2w[:3, :3], camera.R.T, atol=1e-12)
        np.testing.assert_allclose(c2w[:3, 3], camera.center, atol=1e-12)
        # A pixel's centre: (u, v) in mmcsplat, (u + 0.5, v + 0.5) in nerfstudio.
        assert (entry["cx"] - 0.5, entry["cy"] - 0.5, entry["fl_x"], entry["fl_y"]) == pytest.approx(
            (camera.K[0, 2], camera.K[1, 2], camera.K[0, 0], camera.K[1, 1]))
        assert (entry["w"], entry["h"]) == (camera.width, camera.height)
        frame = session.frame(info.frame, name)
        np.testing.assert_array_equal(cv2.imread(str(out / entry["file_path"]))[..., ::-1], frame.rgb)
        np.testing.assert_array_equal(cv2.imread(str(out / entry["mask_path"]), cv2.IMREAD_GRAYSCALE) > 127, frame.mask)
    assert not list(tmp_path.glob(".ns*"))
    assert main(["export", str(runs[1]), "--transforms", str(out)]) == 2  # an existing folder is never replaced


def test_a_transforms_image_that_cannot_be_written_stops_the_export_leaving_nothing(runs, tmp_path, monkeypatch):
    import cv2

    from mmcsplat.outputs.transforms_json import export_transforms

    monkeypatch.setattr(cv2, "imwrite", lambda path, image: False)  # as OpenCV answers on a full disk
    with pytest.raises(OSError, match=r"images/.*\.png: OpenCV could not write it"):
        export_transforms(runs[1], tmp_path / "ns")
    assert not list(tmp_path.iterdir())
