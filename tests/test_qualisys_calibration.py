"""Qualisys Track Manager's ``.qca.txt`` read as cameras, and found in a Pose2Sim project as Pose2Sim ships them."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest
import rig_fixtures as rig

from mmcsplat.pipeline.ingest import ingest
from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import read_calibration, write_calibration


def _text(value: float) -> str:
    return repr(float(value))


def _qca_camera(parent: ElementTree.Element, camera: Camera, left: int = 0, top: int = 0, **attributes: str) -> ElementTree.Element:
    """A <camera> as QTM writes it for ``camera`` (metres), its video a window at (left, top) of the sensor."""
    element = ElementTree.SubElement(parent, "camera", {"active": "1", "serial": camera.name, "model": "Miqus Video",
                                                        "viewrotation": "0", **attributes})
    window = {"left": str(left), "top": str(top), "right": str(left + camera.width - 1), "bottom": str(top + camera.height - 1)}
    for tag in ("fov_marker", "fov_video"):
        ElementTree.SubElement(element, tag, window)
    r = np.diag([1.0, -1.0, -1.0]) @ camera.R  # the world-to-camera rotation of a camera looking down −z, y up
    transform = {f"r{i + 1}{j + 1}": _text(r[i, j]) for i in range(3) for j in range(3)}
    ElementTree.SubElement(element, "transform", {**transform, **{key: _text(1000 * value) for key, value in zip("xyz", camera.center)}})
    k1, k2, p1, p2, k3 = camera.distortion
    ElementTree.SubElement(element, "intrinsic", {
        "focalLengthU": _text(64 * camera.K[0, 0]), "focalLengthV": _text(64 * camera.K[1, 1]),
        "centerPointU": _text(64 * (camera.K[0, 2] + left)), "centerPointV": _text(64 * (camera.K[1, 2] + top)), "skew": "0.000000",
        "radialDistortion1": _text(k1), "radialDistortion2": _text(k2), "radialDistortion3": _text(k3),
        "tangentalDistortion1": _text(p1), "tangentalDistortion2": _text(p2)})
    return element


def _write_qca(path: Path, cameras: list[Camera], extra=None) -> ElementTree.Element:
    root = ElementTree.Element("calibration", {"type": "regular"})
    group = ElementTree.SubElement(root, "cameras")
    for index, camera in enumerate(cameras):
        _qca_camera(group, camera, left=8 * index, top=4 * index)
    if extra:
        extra(group)
    path.parent.mkdir(parents=True, exist_ok=True)
    ElementTree.ElementTree(root).write(path, xml_declaration=True, encoding="ascii")
    return root


def _ring() -> list[Camera]:
    return rig.ring_cameras(["cam01", "cam02", "cam03"], distortion=[-0.05, 0.15, 6e-4, -3e-4, 0.01])


def test_qca_cameras_read_in_metres_with_opencv_axes_and_unscaled_distortion(tmp_path: Path) -> None:
    cameras = _ring()

    def others(group: ElementTree.Element) -> None:
        _qca_camera(group, rig.ring_cameras(["marker"])[0], model="Miqus M3")  # films no video
        _qca_camera(group, rig.ring_cameras(["off"])[0], active="0")

    _write_qca(tmp_path / "Calib.qca.txt", cameras, others)
    read = read_calibration(tmp_path / "Calib.qca.txt", units="m")  # millimetres whatever --units says
    assert [camera.name for camera in read] == ["cam01", "cam02", "cam03"]
    for got, want in zip(read, cameras, strict=True):
        assert (got.width, got.height) == (want.width, want.height)
        np.testing.assert_allclose(got.K, want.K, atol=1e-9)
        np.testing.assert_allclose(got.R, want.R, atol=1e-12)
        np.testing.assert_allclose(got.t, want.t, atol=1e-12)
        np.testing.assert_allclose(got.distortion, want.distortion)
        # the same world point lands on the same pixel
        np.testing.assert_allclose(got.project(rig.MARKERS), want.project(rig.MARKERS), atol=1e-6)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda camera: camera.set("viewrotation", "90"), r"camera 'cam02' \(the 2nd <camera>\): viewrotation 90: QTM turns this camera's view"),
    (lambda camera: camera.find("intrinsic").set("focalLengthU", "wide"), r"camera 'cam02' \(the 2nd <camera>\): <intrinsic> focalLengthU "
                                                                          r"must be a number, got 'wide'"),
    (lambda camera: camera.remove(camera.find("transform")), r"camera 'cam02' \(the 2nd <camera>\): no <transform>"),
    (lambda camera: camera.find("intrinsic").set("skew", "3.5"), r"skew 3.5 is not read"),
])
def test_a_bad_qca_camera_is_named(tmp_path: Path, edit, message: str) -> None:
    root = _write_qca(tmp_path / "Calib.qca.txt", _ring())
    edit(root.findall("cameras/camera")[1])
    ElementTree.ElementTree(root).write(tmp_path / "Calib.qca.txt")
    with pytest.raises(InputError, match=message):
        read_calibration(tmp_path / "Calib.qca.txt")


def test_qca_files_without_video_cameras_or_not_xml_are_refused(tmp_path: Path) -> None:
    root = _write_qca(tmp_path / "Calib.qca.txt", _ring())
    for camera in root.findall("cameras/camera"):
        camera.set("model", "Oqus 7+")
    ElementTree.ElementTree(root).write(tmp_path / "Calib.qca.txt")
    with pytest.raises(InputError, match=r"none of its 3 cameras films video"):
        read_calibration(tmp_path / "Calib.qca.txt")
    (tmp_path / "Calib.qca.txt").write_text("[cam_0]\nname = 'a'\n")
    with pytest.raises(InputError, match=r"Calib.qca.txt: not a Qualisys calibration \(not valid XML"):
        read_calibration(tmp_path / "Calib.qca.txt")


def test_pose2sim_project_with_its_config_and_a_qca_ingests_without_flags(tmp_path: Path) -> None:
    """As Pose2Sim ships its demos: Config.toml at the root (a TOML file of no cameras), the calibration a
    Qualisys file in calibration/, the videos in videos/."""
    project = tmp_path / "project"
    cameras = _ring()
    _write_qca(project / "calibration" / "Calib.qca.txt", cameras)
    (project / "Config.toml").write_text("[project]\nframe_rate = 'auto'\n\n[calibration]\ncalibration_type = 'convert'\n")
    rig.write_videos(project / "videos", cameras, 2)
    session = ingest(project, tmp_path / "s.zarr", progress=False)
    assert list(session.camera_names) == ["cam01", "cam02", "cam03"] and session.num_frames == 2
    assert session.provenance["reader"]["calibration"].endswith("Calib.qca.txt")
    # once Pose2Sim has converted it, both are there: which to use is asked, saying how they differ
    write_calibration(project / "calibration" / "Calib_qualisys.toml", cameras)
    with pytest.raises(InputError, match=r"several calibration files \(Calib.qca.txt, Calib_qualisys.toml\); choose one with "
                                         r"--calibration \(Pose2Sim's conversion of Calib.qca.txt to TOML divides its lens distortion by 64"):
        ingest(project, tmp_path / "both.zarr", progress=False)


def test_a_trial_of_a_pose2sim_batch_takes_its_sessions_calibration(tmp_path: Path) -> None:
    """Pose2Sim's batch layout: the session's Config.toml and calibration/ beside trial folders that hold
    their own Config.toml and videos/."""
    cameras = _ring()
    _write_qca(tmp_path / "batch" / "calibration" / "Calib.qca.txt", cameras)
    (tmp_path / "batch" / "Config.toml").write_text("[project]\nframe_rate = 'auto'\n")
    trial = tmp_path / "batch" / "Trial_1"
    rig.write_videos(trial / "videos", cameras, 2)
    with pytest.raises(MissingFileError, match=r"Trial_1: no calibration.toml.*pass --calibration"):  # not a Pose2Sim trial yet
        ingest(trial, tmp_path / "none.zarr", progress=False)
    (trial / "Config.toml").write_text("[project]\nmulti_person = false\n")
    session = ingest(trial, tmp_path / "s.zarr", progress=False)
    assert session.provenance["reader"]["calibration"] == str(tmp_path / "batch" / "calibration" / "Calib.qca.txt")
