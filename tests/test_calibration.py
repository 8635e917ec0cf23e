"""Calibration I/O: the real anipose and Pose2Sim samples, section order, round trips, malformed files."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import attrs
import cv2
import numpy as np
import pytest
import tomli_w

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import read_calibration, read_rig, write_calibration

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ANIPOSE = SHARED / "aniposelib_calibrations"
POSE2SIM = SHARED / "pose2sim_demo"
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason=f"shared real data not found at {SHARED}")

REAL_SAMPLES = [
    ("allen_mouse_12cam.toml", 12, 5),
    ("allen_mouse_7cam.toml", 7, 5),
    ("motobs_7cam.toml", 7, 5),
    ("mouse_outdoor_adjusted.toml", 12, 5),
    ("Calib_qualisys.toml", 4, 4),
    ("Calib_scene.toml", 4, 4),
]


#: The units each real file's translations are in, as measured: aniposelib's files follow the board (mm),
#: except mouse_outdoor_adjusted.toml, whose cameras lie 0.33–0.91 units from their centroid — metres (in
#: millimetres that would be a rig 2 mm across).
UNITS = {"mouse_outdoor_adjusted.toml": "m"}


def _sample(name: str) -> Path:
    return (POSE2SIM if name.startswith("Calib_") else ANIPOSE) / name


def _units(name: str) -> str:
    return UNITS.get(name, "m" if name.startswith("Calib_") else "mm")


@needs_shared
@pytest.mark.parametrize("name, count, ndist", REAL_SAMPLES)
def test_reads_real_samples(name: str, count: int, ndist: int) -> None:
    path = _sample(name)
    raw = tomllib.loads(path.read_text())
    cameras = read_calibration(path, units=_units(name))
    assert len(cameras) == count
    for camera in cameras:
        table = next(t for k, t in raw.items() if k != "metadata" and t["name"] == camera.name)
        assert camera.distortion.size == ndist
        assert (camera.width, camera.height) == tuple(int(v) for v in table["size"])
        np.testing.assert_allclose(camera.K, table["matrix"])
        # Compare matrices: a Rodrigues vector longer than π has an equivalent shorter twin.
        np.testing.assert_allclose(camera.R, cv2.Rodrigues(np.array(table["rotation"]))[0], atol=1e-12)
        scale = 1e-3 if _units(name) == "mm" else 1.0
        np.testing.assert_allclose(camera.t, np.array(table["translation"]) * scale)


@needs_shared
@pytest.mark.parametrize("name", [name for name, _, _ in REAL_SAMPLES])
def test_real_files_in_the_wrong_units_are_refused_with_the_right_ones_suggested(name: str) -> None:
    right = _units(name)
    wrong = {"m": "mm", "mm": "m"}[right]
    with pytest.raises(ValueError, match=rf"cameras lie up to .* m from their centre read in {wrong}, outside the 0.05–50 m.*pass --units {right}"):
        read_calibration(_sample(name), units=wrong)


@needs_shared
def test_pose2sim_sample_projects_in_front_of_cameras() -> None:
    cameras = read_calibration(POSE2SIM / "Calib_qualisys.toml")
    assert [c.name for c in cameras] == ["cam_01", "cam_02", "cam_03", "cam_04"]
    assert (cameras[0].width, cameras[0].height) == (1088, 1920)
    # The subject stands near the world origin: in front of every camera, within a few metres.
    for camera in cameras:
        depth = (camera.R @ np.zeros(3) + camera.t)[2]
        assert 1.0 < depth < 6.0, camera.name


@needs_shared
def test_anipose_sections_ordered_by_number(tmp_path: Path) -> None:
    source = ANIPOSE / "allen_mouse_12cam.toml"
    raw = tomllib.loads(source.read_text())
    expected = [raw[f"cam_{i}"]["name"] for i in range(12)]
    assert [c.name for c in read_calibration(source, units="mm")] == expected
    # The same tables written in text order (cam_0, cam_1, cam_10, cam_11, cam_2, …) read back by number.
    shuffled = {key: raw[key] for key in sorted(raw)}
    assert list(shuffled)[:4] == ["cam_0", "cam_1", "cam_10", "cam_11"]
    path = tmp_path / "calibration.toml"
    path.write_text(tomli_w.dumps(shuffled))
    assert [c.name for c in read_calibration(path, units="mm")] == expected


def _cameras() -> list[Camera]:
    rng = np.random.default_rng(0)
    cameras = []
    for i, distortion in enumerate(([-0.2, 0.05, 1e-3, -2e-3, 0.01], [-0.1, 0.02, 0.0, 0.0], [])):
        K = [[800.0 + i, 0, 320.5], [0, 805.0, 240.25], [0, 0, 1]]
        cameras.append(Camera(f"cam{i}", 640, 480, K, rng.normal(size=3), rng.normal(size=3), distortion))
    return cameras


@pytest.mark.parametrize("units", ["m", "mm"])
def test_write_read_round_trip(tmp_path: Path, units: str) -> None:
    cameras = _cameras()
    path = tmp_path / "calibration.toml"
    write_calibration(path, cameras, units=units, metadata={"source": "test"})
    raw = tomllib.loads(path.read_text())
    assert list(raw) == ["cam_0", "cam_1", "cam_2", "metadata"]
    assert raw["metadata"] == {"source": "test"}
    factor = 1000.0 if units == "mm" else 1.0
    np.testing.assert_allclose(raw["cam_0"]["translation"], cameras[0].t * factor)
    back = read_calibration(path, units=units)
    assert [c.name for c in back] == [c.name for c in cameras]
    for original, read in zip(cameras, back):
        assert (read.width, read.height) == (original.width, original.height)
        np.testing.assert_allclose(read.K, original.K)
        np.testing.assert_allclose(read.R, original.R, atol=1e-12)
        np.testing.assert_allclose(read.t, original.t, rtol=1e-12)
        padded = np.zeros(5)
        padded[: original.distortion.size] = original.distortion
        np.testing.assert_allclose(read.distortion, padded)
    assert not list(tmp_path.glob(".*.tmp")), "temporary file left behind"


@needs_shared
@pytest.mark.parametrize("name", [name for name, _, _ in REAL_SAMPLES])
def test_auto_units_read_each_real_file_in_its_measured_units(name: str) -> None:
    rig = read_rig(_sample(name))  # units="auto", ingest's and run's default
    assert rig.units == _units(name)
    expected = read_calibration(_sample(name), units=_units(name))
    np.testing.assert_array_equal([camera.t for camera in rig.cameras], [camera.t for camera in expected])


def test_auto_units_refuse_a_rig_implausible_either_way_and_take_metres_for_one_camera(tmp_path: Path) -> None:
    path = tmp_path / "calibration.toml"
    write_calibration(path, [attrs.evolve(camera, t=camera.t * 1e8) for camera in _cameras()])
    with pytest.raises(InputError, match=rf"calibration {re.escape(str(path))}: the cameras lie up to .* units from their centre, outside "
                       "the 0.05–50 m of any real rig whether the units are metres or millimetres"):
        read_rig(path)
    write_calibration(path, _cameras()[:1], units="mm")
    assert read_rig(path).units == "m"


def test_units_scale_translations_and_a_mismatch_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "calibration.toml"
    write_calibration(path, _cameras(), units="mm")
    np.testing.assert_allclose(read_calibration(path, units="mm")[0].t, _cameras()[0].t)
    with pytest.raises(ValueError, match="pass --units mm"):  # a rig kilometres across: the file is in millimetres
        read_calibration(path, units="m")
    with pytest.raises(ValueError, match="units 'cm'"):
        read_calibration(path, units="cm")


GOOD = {
    "name": "a",
    "size": [640, 480],
    "matrix": [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]],
    "distortions": [0.0, 0.0, 0.0, 0.0, 0.0],
    "rotation": [0.0, 0.0, 0.0],
    "translation": [0.0, 0.0, 1.0],
}


@pytest.mark.parametrize(
    "change, message",
    [
        ({"matrix": None}, r"\[cam_0\]: missing matrix"),
        ({"matrix": [[1.0, 0.0], [0.0, 1.0]]}, r"\[cam_0\]: matrix must have shape \[3, 3\]"),
        ({"distortions": [0.1, 0.2, 0.3]}, r"\[cam_0\]: distortions must hold 4"),
        ({"size": [640.5, 480]}, r"\[cam_0\]: size must be two positive whole numbers"),
        ({"rotation": ["x", 0, 0]}, r"\[cam_0\]: rotation must be numbers"),
        ({"translation": [0.0, 1.0]}, r"\[cam_0\]: translation must have shape \[3\]"),
        ({"name": 3}, r", \[cam_0\]: name must be a string, got 3"),
    ],
)
def test_malformed_tables_name_file_and_section(tmp_path: Path, change: dict, message: str) -> None:
    table = {key: value for key, value in {**GOOD, **change}.items() if value is not None}
    path = tmp_path / "broken.toml"
    path.write_text(tomli_w.dumps({"cam_0": table, "metadata": {}}))
    with pytest.raises(ValueError, match=message) as error:
        read_calibration(path)
    assert str(path) in str(error.value)


@pytest.mark.parametrize(
    "text, message",
    [
        ("[cam_0\nname = 1", "not valid TOML"),
        ("[metadata]\nerror = 0.1\n", "no camera tables"),
        ("stray = 1\n", "unexpected top-level key 'stray'"),
    ],
)
def test_malformed_documents(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "broken.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        read_calibration(path)
    assert str(path) in str(error.value)


def test_duplicate_camera_names(tmp_path: Path) -> None:
    path = tmp_path / "calibration.toml"
    path.write_text(tomli_w.dumps({"cam_0": GOOD, "cam_1": GOOD}))
    with pytest.raises(ValueError, match=r"\['a'\] appear more than once"):
        read_calibration(path)


def test_missing_file() -> None:
    with pytest.raises(FileNotFoundError):
        read_calibration(Path("/nonexistent/calibration.toml"))


@pytest.mark.parametrize("edit, message", [
    (lambda t: t["matrix"][0].__setitem__(0, 0.0), "focal lengths 0, 500 pixels; both must be > 0"),
    (lambda t: t["matrix"][0].__setitem__(2, 5000.0), r"principal point \(5000, 240\) far outside its 640×480 image"),
    (lambda t: t.__setitem__("translation", [0, 0, 1e308]), "outside the 0.05–50 m of any real rig"),
    (lambda t: t.__setitem__("matrix", [[500.0, 0, 0], [0, 500.0, 0], [320, 240, 1]]), r"camera 'c1': K .* is not an intrinsic matrix .*: "
                                                                                     r"it is one transposed \(MATLAB's layout\)"),
    (lambda t: t["matrix"][2].__setitem__(2, 2.0), r"camera 'c1': K .* is not an intrinsic matrix \[\[fx, skew, cx\], \[0, fy, cy\], \[0, 0, 1\]\]$"),
    (lambda t: t.__setitem__("rotation", [[1.0, 0.3, 0], [0, 1.0, 0], [0, 0, 1.0]]), r"camera 'c1': R is not a rotation \(its rows are 0.3 "),
    # cam_0's pose 5 mm aside: a camera whose translation was written in another unit lands beside another
    (lambda t: t.update(rotation=[0.0, 0.0, 0.0], translation=[0.005, 0.0, 2.0]), "cameras 'c0' and 'c1' stand 5 mm apart read in m, closer "
                                                                                  "than any two cameras of a rig"),
])
def test_impossible_cameras_are_refused_naming_them(tmp_path: Path, edit, message) -> None:
    cameras = {f"cam_{i}": {**GOOD, "name": f"c{i}", "matrix": [list(row) for row in GOOD["matrix"]],
                            "rotation": [0.0, 0.1 * i, 0.0], "translation": [0.1 * i, 0.0, 2.0]} for i in range(3)}
    edit(cameras["cam_1"])
    path = tmp_path / "calibration.toml"
    path.write_text(tomli_w.dumps(cameras))
    with pytest.raises(ValueError, match=message) as caught:
        read_calibration(path)
    assert str(path) in str(caught.value)


def test_two_cameras_with_one_pose_are_named(tmp_path: Path) -> None:
    cameras = {f"cam_{i}": {**GOOD, "name": f"c{i}", "rotation": [0.0, 0.1 * i, 0.0], "translation": [0.1 * i, 0.0, 2.0]} for i in range(3)}
    cameras["cam_2"] = {**cameras["cam_1"], "name": "c2"}  # a copied table with its name changed
    path = tmp_path / "calibration.toml"
    path.write_text(tomli_w.dumps(cameras))
    with pytest.raises(ValueError, match="cameras 'c1' and 'c2' have the same pose"):
        read_calibration(path)


def test_a_bad_value_names_the_file_and_table_once(tmp_path: Path) -> None:
    path = tmp_path / "calibration.toml"
    path.write_text(tomli_w.dumps({"cam_0": {**GOOD, "matrix": [[1, 2], [3, 4]]}}))
    with pytest.raises(ValueError) as caught:
        read_calibration(path)
    assert str(caught.value).count(str(path)) == 1 and "matrix must have shape [3, 3]" in str(caught.value)


def _caliscope_table(camera: Camera, number: int, rotation: str) -> dict:
    """Camera ``camera`` as Caliscope's camera_array.toml holds it: ``rotation`` "rodrigues" (what it writes
    now) or "matrix" (what it wrote before), with the workspace fields it adds."""
    distortion = np.zeros(5)
    distortion[: camera.distortion.size] = camera.distortion
    return {"cam_id": number, "size": [camera.width, camera.height], "rotation_count": 1, "error": 0.3,
            "matrix": camera.K.tolist(), "distortions": distortion.tolist(), "translation": camera.t.tolist(),
            "rotation": camera.rvec.tolist() if rotation == "rodrigues" else camera.R.tolist(), "exposure": -6, "grid_count": 20}


@pytest.mark.parametrize("rotation", ["rodrigues", "matrix"])
def test_caliscope_camera_array_read_by_number_leaving_out_unplaced_and_ignored_cameras(tmp_path: Path, rotation: str) -> None:
    cameras = _cameras()
    tables = {str(number): _caliscope_table(camera, number, rotation) for number, camera in zip((10, 2, 7), cameras)}
    tables["3"] = {**_caliscope_table(cameras[0], 3, rotation), "rotation": "null", "translation": "null"}  # written before: "null"
    tables["4"] = {key: value for key, value in _caliscope_table(cameras[1], 4, rotation).items() if key != "rotation"}
    tables["5"] = {**_caliscope_table(cameras[2], 5, rotation), "ignore": True}
    path = tmp_path / "camera_array.toml"
    path.write_text(tomli_w.dumps({"cameras": tables}))
    read = read_calibration(path)
    assert [camera.name for camera in read] == ["cam_2", "cam_7", "cam_10"]  # by number, not text: 10 after 7
    for original, camera in zip((cameras[1], cameras[2], cameras[0]), read):
        np.testing.assert_allclose(camera.K, original.K)
        np.testing.assert_allclose(camera.R, original.R, atol=1e-12)
        np.testing.assert_allclose(camera.t, original.t)
    assert [camera.name for camera in read_calibration(path, cameras=["cam_7"])] == ["cam_7"]
    with pytest.raises(ValueError, match=r"no camera named 'cam_3'"):
        read_calibration(path, cameras=["cam_3"])


def test_caliscope_files_without_placed_cameras_or_with_unnumbered_tables_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "camera_array.toml"
    unplaced = {key: value for key, value in _caliscope_table(_cameras()[0], 0, "rodrigues").items() if key not in ("rotation", "translation")}
    path.write_text(tomli_w.dumps({"cameras": {"0": unplaced}}))
    with pytest.raises(ValueError, match=r"camera_array.toml: Caliscope has placed none of its cameras"):
        read_calibration(path)
    path.write_text(tomli_w.dumps({"cameras": {"left": _caliscope_table(_cameras()[0], 0, "rodrigues")}}))
    with pytest.raises(ValueError, match=r"\[cameras.left\]: Caliscope's camera tables are numbered"):
        read_calibration(path)
    path.write_text(tomli_w.dumps({"cameras": {"0": {**_caliscope_table(_cameras()[0], 0, "rodrigues"), "rotation": [1.0, 2.0]}}}))
    with pytest.raises(ValueError, match=r"\[cameras.0\]: rotation must be a Rodrigues vector \[3\] or a matrix \[3, 3\]"):
        read_calibration(path)


@needs_shared
def test_a_camera_whose_pose_is_inverted_is_said_and_no_real_rig_warns(tmp_path: Path) -> None:
    """A pose written camera-to-world (R and t of the inverse) puts a camera where it cannot see what the others
    look at; every camera of the real rigs sees it."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no real rig's camera is taken for an inverted one
        for name, _, _ in REAL_SAMPLES:
            read_rig(_sample(name))
    cameras = read_calibration(_sample("Calib_qualisys.toml"))
    inverted = [*cameras[:2], attrs.evolve(cameras[2], R=cameras[2].R.T, t=cameras[2].center), *cameras[3:]]
    write_calibration(tmp_path / "calibration.toml", inverted)
    with pytest.warns(UserWarning, match=r"camera 'cam_03' does not see the point the other cameras look at .*: is its pose the inverse"):
        read_rig(tmp_path / "calibration.toml")
