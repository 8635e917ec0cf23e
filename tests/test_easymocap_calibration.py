"""EasyMocap's intri.yml + extri.yml: round trips through OpenCV's FileStorage, units, the rotation's two
spellings, image sizes from the decoded frames, malformed files, finding the pair, and ingest."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
import pytest
import rig_fixtures as rig

from mmcsplat.datasets.rig import find_calibration
from mmcsplat.pipeline.ingest import detect_format, ingest
from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import read_calibration, write_calibration

NAMES = ("cam_a", "cam_b", "cam_c")


def write_easymocap(folder: Path, cameras: Sequence[Camera], *, metres_per_unit: float = 1.0, sizes: bool = True,
                    rotations: Sequence[str] = ("Rot", "R"), skip: Sequence[str] = (), replace: Mapping[str, np.ndarray] | None = None,
                    extri_names: Sequence[str] | None = None) -> None:
    """``cameras`` as EasyMocap writes them (H_/W_ when ``sizes``; ``rotations`` of Rot_ and R_), less the
    keys in ``skip``, with the matrices in ``replace`` instead of the cameras' own."""
    folder.mkdir(parents=True, exist_ok=True)
    replace = replace or {}
    intri = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(folder / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    for storage, names in ((intri, [c.name for c in cameras]), (extri, extri_names or [c.name for c in cameras])):
        storage.startWriteStruct("names", cv2.FileNode_SEQ)
        for name in names:
            storage.write("", name)
        storage.endWriteStruct()
    for camera in cameras:
        n = camera.name
        entries = [(intri, f"K_{n}", camera.K), (intri, f"dist_{n}", camera.distortion.reshape(1, -1))]
        entries += [(intri, f"H_{n}", camera.height), (intri, f"W_{n}", camera.width)] if sizes else []
        entries += [(extri, f"R_{n}", camera.rvec.reshape(3, 1))] if "R" in rotations else []
        entries += [(extri, f"Rot_{n}", camera.R)] if "Rot" in rotations else []
        entries += [(extri, f"T_{n}", camera.t.reshape(3, 1) / metres_per_unit)]
        for storage, key, value in entries:
            if key not in skip:
                storage.write(key, replace.get(key, value))
    intri.release()
    extri.release()


def assert_same_cameras(read: Sequence[Camera], expected: Sequence[Camera], atol: float = 1e-12) -> None:
    assert [c.name for c in read] == [c.name for c in expected]
    for camera, original in zip(read, expected, strict=True):
        assert (camera.width, camera.height, camera.fisheye) == (original.width, original.height, original.fisheye)
        np.testing.assert_allclose(camera.K, original.K, atol=atol)
        np.testing.assert_allclose(camera.R, original.R, atol=atol)
        np.testing.assert_allclose(camera.t, original.t, atol=atol)
        np.testing.assert_allclose(camera.distortion, original.distortion, atol=atol)


@pytest.mark.parametrize("rotations", [("Rot", "R"), ("R",), ("Rot",)])
def test_round_trip_through_either_file_or_the_folder(tmp_path: Path, rotations: Sequence[str]) -> None:
    cameras = rig.ring_cameras(NAMES)
    write_easymocap(tmp_path, cameras, rotations=rotations)
    for path in (tmp_path / "intri.yml", tmp_path / "extri.yml", tmp_path):
        assert_same_cameras(read_calibration(path), cameras)


def test_the_text_easymocap_writes(tmp_path: Path) -> None:
    """EasyMocap writes its files as text: a %YAML:1.0 header, CRLF, quoted names, 6 decimals; older files
    call the distortion D_."""
    cameras = rig.ring_cameras(["01", "02"])

    def matrix(key: str, value: np.ndarray) -> list[str]:
        data = ", ".join(f"{v:.6f}" for v in value.reshape(-1))
        return [f"{key}: !!opencv-matrix", f"  rows: {value.shape[0]}", f"  cols: {value.shape[1]}", "  dt: d", f"  data: [{data}]"]

    header = ["%YAML:1.0", "---", "names:", '  - "01"', '  - "02"']
    intri = header + [line for c in cameras for line in matrix(f"K_{c.name}", c.K) + matrix(f"D_{c.name}", c.distortion.reshape(1, 5))
                      + [f"H_{c.name}: {c.height}", f"W_{c.name}: {c.width}"]]
    extri = header + [line for c in cameras for line in matrix(f"R_{c.name}", c.rvec.reshape(3, 1)) + matrix(f"Rot_{c.name}", c.R)
                      + matrix(f"T_{c.name}", c.t.reshape(3, 1))]
    for name, lines in (("intri.yml", intri), ("extri.yml", extri)):
        (tmp_path / name).write_bytes(("\r\n".join(lines) + "\r\n").encode())
    assert_same_cameras(read_calibration(tmp_path), cameras, atol=2e-6)


def test_millimetres_and_a_choice_of_cameras(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(NAMES)
    write_easymocap(tmp_path, cameras, metres_per_unit=1e-3, skip=["K_cam_b"])  # cam_b is broken: left out, never read
    assert_same_cameras(read_calibration(tmp_path, "mm", ["cam_c", "cam_a"]), [cameras[0], cameras[2]])
    with pytest.raises(InputError, match="read in m, outside the .* if the file is in mm, pass --units mm"):
        read_calibration(tmp_path, "m", ["cam_a", "cam_c"])
    with pytest.raises(InputError, match="no camera named 'cam_x'; cameras are cam_a, cam_b, cam_c"):
        read_calibration(tmp_path, "mm", ["cam_x"])


def test_a_file_without_image_sizes_takes_them_from_the_images_and_never_guesses(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(NAMES)
    write_easymocap(tmp_path, cameras, sizes=False)
    with pytest.raises(InputError, match=r"intri\.yml: camera 'cam_a': no image size \(H_cam_a, W_cam_a\) and no images to take it from"):
        read_calibration(tmp_path)
    assert_same_cameras(read_calibration(tmp_path, sizes={c.name: (c.width, c.height) for c in cameras}), cameras)
    # The given size is checked like a stated one: this principal point lies far outside a 20×20 image.
    with pytest.raises(InputError, match="camera 'cam_a' has its principal point .* far outside its 20×20 image"):
        read_calibration(tmp_path, sizes={c.name: (20, 20) for c in cameras})
    write_easymocap(tmp_path, cameras)  # a stated size wins over the images'
    assert read_calibration(tmp_path, sizes={c.name: (20, 20) for c in cameras})[0].width == cameras[0].width


@pytest.mark.parametrize("edit, file, message", [
    ({"skip": ["K_cam_b"]}, "intri.yml", "camera 'cam_b': missing K_cam_b"),
    ({"skip": ["dist_cam_b"]}, "intri.yml", "camera 'cam_b': missing dist_cam_b"),
    ({"skip": ["W_cam_b"]}, "intri.yml", "camera 'cam_b': H_cam_b without W_cam_b"),
    ({"skip": ["T_cam_c"]}, "extri.yml", "camera 'cam_c': missing T_cam_c"),
    ({"skip": ["R_cam_c", "Rot_cam_c"]}, "extri.yml", r"camera 'cam_c': missing Rot_cam_c \(or its Rodrigues vector R_cam_c\)"),
    ({"replace": {"K_cam_a": np.eye(3)[:2]}}, "intri.yml", "camera 'cam_a': K_cam_a must be 3×3, got 2×3"),
    ({"replace": {"dist_cam_a": np.zeros((1, 3))}}, "intri.yml", r"camera 'cam_a': dist_cam_a must hold 4 \(k1 k2 p1 p2\) or 5"),
    ({"replace": {"dist_cam_a": np.full((1, 8), 0.01)}}, "intri.yml", "dist_cam_a holds 8 coefficients; only k1 k2 p1 p2 k3"),
    ({"replace": {"T_cam_a": np.zeros((2, 1))}}, "extri.yml", "camera 'cam_a': T_cam_a must hold 3 values, got 2"),
    ({"replace": {"Rot_cam_a": 2 * np.eye(3)}}, "extri.yml", "camera 'cam_a': Rot_cam_a is not a rotation matrix"),
    ({"replace": {"R_cam_b": rig.ring_cameras(NAMES)[1].rvec.reshape(3, 1) + 1e-3}}, "extri.yml",
     "camera 'cam_b': Rot_cam_b and R_cam_b disagree by 0.0"),
    ({"extri_names": ["cam_a", "cam_b", "cam_x"]}, "extri.yml", r"its names differ from intri\.yml's: cameras 'cam_x' only in "
                                                                r"extri\.yml; 'cam_c' only in intri\.yml"),
])
def test_bad_files_are_refused_naming_the_file_and_camera(tmp_path: Path, edit: dict, file: str, message: str) -> None:
    write_easymocap(tmp_path, rig.ring_cameras(NAMES), **edit)
    with pytest.raises(InputError, match=message) as caught:
        read_calibration(tmp_path)
    assert str(tmp_path / file) in str(caught.value)


def test_missing_and_unreadable_files(tmp_path: Path) -> None:
    write_easymocap(tmp_path, rig.ring_cameras(NAMES))
    (tmp_path / "extri.yml").write_text("names: [cam_a\nT_cam_a: {")
    with pytest.raises(InputError, match=rf"calibration {tmp_path / 'extri.yml'}: not valid OpenCV YAML \(line"):
        read_calibration(tmp_path)
    (tmp_path / "extri.yml").unlink()
    with pytest.raises(MissingFileError, match=rf"calibration {tmp_path / 'extri.yml'} does not exist"):
        read_calibration(tmp_path / "intri.yml")
    with pytest.raises(MissingFileError, match=rf"calibration file {tmp_path / 'extri.yml'} does not exist"):
        find_calibration(tmp_path, tmp_path / "intri.yml")


def test_the_pair_is_found_beside_the_capture_or_named(tmp_path: Path) -> None:
    source = tmp_path / "capture"
    write_easymocap(source, rig.ring_cameras(NAMES))
    for given in (None, source / "intri.yml", source / "extri.yml", source):
        assert find_calibration(source, given) == source / "intri.yml"
    for name in ("intri.yml", "extri.yml"):  # where Pose2Sim and anipose keep theirs
        (source / name).unlink()
    write_easymocap(source / "calibration", rig.ring_cameras(NAMES))
    assert find_calibration(source, None) == source / "calibration" / "intri.yml"
    write_calibration(source / "calibration" / "Calib_scene.toml", rig.ring_cameras(NAMES))
    with pytest.raises(InputError, match=r"several calibration files \(Calib_scene\.toml, intri\.yml\); choose one with --calibration"):
        find_calibration(source, None)
    with pytest.raises(MissingFileError, match="no calibration.toml, other single .*toml of cameras, Qualisys .*qca.txt, EasyMocap intri.yml . extri.yml, or OpenCap camera folders. cameraIntrinsicsExtrinsics.pickle in it"):
        find_calibration(source, source)


@pytest.mark.parametrize("layout", ["videos", "images"])
def test_ingest_without_sizes_stores_the_cameras_a_toml_gives(tmp_path: Path, layout: str) -> None:
    """ZJU-MoCap's layout: intri.yml and extri.yml (without H_/W_) at the capture's root beside videos/ or
    images/, one per camera; ingested as with the same cameras in a calibration.toml."""
    cameras = rig.ring_cameras(NAMES[:2])
    source = tmp_path / "capture"
    if layout == "videos":
        rig.write_videos(source / "videos", cameras, 3)
    else:
        rig.write_image_folders(source / "images", cameras, 3)
    write_easymocap(source, cameras, sizes=False)
    write_calibration(tmp_path / "calibration.toml", cameras)
    assert detect_format(source) == layout
    options = {"progress": False, "scale": 0.5, "reader_options": {"fps": 30.0} if layout == "images" else None}
    from_yml = ingest(source, tmp_path / "yml.zarr", **options)
    from_toml = ingest(source, tmp_path / "toml.zarr", calibration=tmp_path / "calibration.toml", **options)
    assert from_yml.provenance["reader"]["calibration"] == str(source / "intri.yml")
    assert_same_cameras([from_yml.camera(n) for n in NAMES[:2]], [from_toml.camera(n) for n in NAMES[:2]])
    for name in NAMES[:2]:
        np.testing.assert_array_equal(from_yml.frame(2, name).rgb, from_toml.frame(2, name).rgb)
