"""The zarr session store: round trips, sparse frames, the byte-bounded cache, atomic writes and updates."""

from __future__ import annotations

import uuid

import attrs
import fsspec
import numpy as np
import pytest

from mmcsplat.scene.camera import Camera
from mmcsplat.storage.session import (
    AbsentFrameError,
    FrameCache,
    IncompleteSessionError,
    SessionFrame,
    SessionReader,
    SessionUpdater,
    SessionWriter,
)

T = 4


def make_cameras() -> list[Camera]:
    """Two cameras of different image sizes, looking at the origin from either side."""
    K = [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]
    flip = np.diag([-1.0, 1.0, -1.0])
    return [
        Camera("left", 32, 24, K, np.eye(3), [0, 0, 2.0]),
        Camera("right", 20, 10, [[30.0, 0, 9.5], [0, 30.0, 4.5], [0, 0, 1]], flip, [0.1, 0, 2.0], distortion=[0, 0, 0, 0]),
    ]


def fields_of(camera: Camera, t: int) -> dict[str, np.ndarray]:
    """Distinct, deterministic data for every field of one frame."""
    rng = np.random.default_rng([t, camera.width])
    h, w = camera.height, camera.width
    return {
        "rgb": rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
        "mask": rng.random((h, w)) > 0.5,
        "depth": rng.uniform(0.5, 3.0, (h, w)).astype(np.float32),
        "labels": rng.integers(0, 150, (h, w)).astype(np.uint16),
    }


@pytest.fixture(params=["local", "memory"])
def url(request, tmp_path):
    """A fresh session location: a local directory, or an fsspec in-memory URL removed afterwards."""
    if request.param == "local":
        yield str(tmp_path / "session.zarr")
    else:
        location = f"memory://store-tests/{uuid.uuid4().hex}/session.zarr"
        yield location
        fs, path = fsspec.core.url_to_fs(location)
        if fs.exists(path):
            fs.rm(path, recursive=True)


def write_session(url: str, **options) -> list[Camera]:
    """A complete session: every field for 'left'; only rgb at frames 1 and 3 for 'right'."""
    cameras = make_cameras()
    left, right = cameras
    with SessionWriter(url, cameras=cameras, num_frames=T, fps=30.0, heldout=["right"], source="unit test", **options) as writer:
        for t in range(T):
            data = fields_of(left, t)
            writer.write_frame("left", t, data["rgb"], mask=data["mask"], depth=data["depth"], labels=data["labels"])
        for t in (1, 3):
            writer.write_frame("right", t, fields_of(right, t)["rgb"])
    return cameras


def exists(url: str) -> bool:
    fs, path = fsspec.core.url_to_fs(url)
    return fs.exists(path)


def test_round_trip_of_every_field(url):
    cameras = write_session(url, provenance={"operator": "test"})
    reader = SessionReader(url)
    assert reader.camera_names == ("left", "right")
    assert reader.heldout == ("right",) and reader.train_cameras == ("left",)
    assert reader.num_frames == T and reader.fps == 30.0 and reader.source == "unit test"
    np.testing.assert_allclose(reader.frame_times, np.arange(T) / 30.0)
    assert reader.provenance["operator"] == "test" and "created" in reader.provenance
    for stored, original in zip(reader.cameras, cameras, strict=True):
        assert (stored.width, stored.height) == (original.width, original.height)
        np.testing.assert_array_equal(stored.K, original.K)
        np.testing.assert_array_equal(stored.R, original.R)
        np.testing.assert_array_equal(stored.t, original.t)
    assert reader.camera("right").width == 20

    for t in range(T):
        expected, frame = fields_of(cameras[0], t), reader.frame(t, "left")
        np.testing.assert_array_equal(frame.rgb, expected["rgb"])
        np.testing.assert_array_equal(frame.mask, expected["mask"])
        np.testing.assert_array_equal(frame.labels, expected["labels"])
        assert frame.depth.dtype == np.float32
        np.testing.assert_allclose(frame.depth, expected["depth"], rtol=1e-3)  # stored as float16
        assert frame.rgb.dtype == np.uint8 and frame.mask.dtype == bool and frame.labels.dtype == np.uint16
    frame = reader.frame(3, "right")
    np.testing.assert_array_equal(frame.rgb, fields_of(cameras[1], 3)["rgb"])
    assert frame.mask is None and frame.depth is None and frame.labels is None


def test_a_clean_plate_per_camera_round_trips(url):
    cameras = make_cameras()
    plate = fields_of(cameras[0], 9)["rgb"]
    with SessionWriter(url, cameras=cameras, num_frames=1, fps=30.0) as writer:
        writer.write_frame("left", 0, fields_of(cameras[0], 0)["rgb"])
        writer.write_plate("left", plate)
        with pytest.raises(ValueError, match=r"camera 'right' plate: rgb must be uint8 \[10, 20, 3\], got uint8 \[24, 32, 3\]"):
            writer.write_plate("right", plate)
        with pytest.raises(ValueError, match=r"unknown camera 'top'"):
            writer.write_plate("top", plate)
    reader = SessionReader(url)
    np.testing.assert_array_equal(reader.plate("left"), plate)
    assert reader.plate("right") is None and not reader.plate("left").flags.writeable
    with pytest.raises(ValueError, match="unknown camera 'top'"):
        reader.plate("top")


def test_a_version_1_session_reads_without_plates(tmp_path):
    import zarr

    write_session(tmp_path / "old.zarr")
    group = zarr.open_group(str(tmp_path / "old.zarr"), mode="r+")
    group.attrs.pop("plates")
    group.attrs["mmcsplat_session"] = 1
    assert "plates" not in zarr.open_group(str(tmp_path / "old.zarr"), mode="r").attrs
    assert SessionReader(tmp_path / "old.zarr").plate("left") is None


def test_present_says_which_frames_exist(url):
    write_session(url)
    reader = SessionReader(url)
    np.testing.assert_array_equal(reader.present("left"), [True] * T)
    np.testing.assert_array_equal(reader.present("right"), [False, True, False, True])
    assert reader.has("mask") and reader.has("depth", "left") and not reader.has("mask", "right")
    with pytest.raises(AbsentFrameError, match=r"frame 2 of camera 'right'"):
        reader.frame(2, "right")
    with pytest.raises(IndexError, match=r"camera 'left': frame 4 is out of range"):
        reader.frame(T, "left")
    with pytest.raises(ValueError, match=r"unknown camera 'top'"):
        reader.frame(0, "top")
    with pytest.raises(ValueError, match=r"unknown session field 'normals'"):
        reader.has("normals")


def test_frame_cache_is_bounded_in_bytes_and_evicts_least_recently_used():
    def item(nbytes: int) -> SessionFrame:
        return SessionFrame(rgb=np.zeros(nbytes, dtype=np.uint8))

    cache = FrameCache(300)
    cache.put("a", item(100))
    cache.put("b", item(100))
    cache.put("c", item(100))
    assert cache.get("a") is not None  # a is now the most recently used: b goes first
    cache.put("d", item(100))
    assert "b" not in cache and all(key in cache for key in "acd")
    assert cache.current_bytes == 300 and len(cache) == 3
    cache.put("e", item(250))  # needs the room of c, d and a, in that order
    assert "e" in cache and "a" not in cache and cache.current_bytes == 250
    cache.put("huge", item(301))
    assert "huge" not in cache and "e" in cache
    cache.put("e", item(50))  # replacing a value updates the byte count
    assert cache.current_bytes == 50
    assert cache.get("zzz") is None
    assert (cache.hits, cache.misses) == (1, 1)


def test_frame_cache_returns_freed_memory_after_every_trim_bytes_stored(monkeypatch):
    import mmcsplat.storage.session.cache as cache

    released = []
    monkeypatch.setattr(cache, "TRIM_BYTES", 250)
    monkeypatch.setattr(cache, "release_freed_memory", lambda: released.append(True) or True)
    cache = FrameCache(300)
    for index in range(6):  # 100 bytes at a time, evicting as it goes: a return after the 3rd and the 6th
        cache.put(index, SessionFrame(rgb=np.zeros(100, dtype=np.uint8)))
    assert len(released) == 2
    cache.put("huge", SessionFrame(rgb=np.zeros(301, dtype=np.uint8)))  # not stored, not counted
    assert len(released) == 2


def test_release_freed_memory_finds_malloc_trim_on_glibc():
    import platform

    from mmcsplat.storage.memory import malloc_trim_function, release_freed_memory

    if platform.libc_ver()[0] == "glibc":
        assert malloc_trim_function() is not None
    assert isinstance(release_freed_memory(), bool)


def test_reader_cache_hits_and_stays_in_budget(tmp_path):
    url = tmp_path / "session.zarr"
    write_session(url)
    frame_bytes = SessionReader(url).frame(0, "left").nbytes  # rgb + mask + depth (float32) + labels
    assert frame_bytes == 24 * 32 * (3 + 1 + 4 + 2)

    reader = SessionReader(url, cache_bytes=2 * frame_bytes)
    first = reader.frame(0, "left")
    assert reader.frame(0, "left") is first and reader.cache.hits == 1
    with pytest.raises(ValueError, match="read-only"):
        first.rgb[0, 0, 0] = 1  # a cached frame cannot be corrupted by a caller
    for t in range(T):
        reader.frame(t, "left")
        assert reader.cache.current_bytes <= 2 * frame_bytes
    assert len(reader.cache) == 2 and (reader.cache.hits, reader.cache.misses) == (2, 4)
    assert (("left", 2) in reader.cache, ("left", 3) in reader.cache, ("left", 0) in reader.cache) == (True, True, False)

    tiny = SessionReader(url, cache_bytes=frame_bytes - 1)  # larger than the budget: returned, not kept
    assert tiny.frame(1, "left").rgb.shape == (24, 32, 3)
    assert len(tiny.cache) == 0 and tiny.cache.current_bytes == 0


def test_bad_frames_are_refused_naming_camera_and_frame(url):
    cameras = make_cameras()
    good = fields_of(cameras[0], 0)
    with SessionWriter(url, cameras=cameras, num_frames=T, fps=30.0) as writer:
        with pytest.raises(ValueError, match=r"camera 'left' frame 2: rgb must be uint8 \[24, 32, 3\], got float32"):
            writer.write_frame("left", 2, good["rgb"].astype(np.float32))
        with pytest.raises(ValueError, match=r"camera 'right' frame 1: rgb must be uint8 \[10, 20, 3\], got uint8 \[24, 32, 3\]"):
            writer.write_frame("right", 1, good["rgb"])
        with pytest.raises(ValueError, match=r"camera 'left' frame 0: mask must be bool"):
            writer.write_frame("left", 0, good["rgb"], mask=good["mask"].astype(np.uint8))
        with pytest.raises(ValueError, match=r"camera 'left' frame 0: labels must be uint8 or uint16"):
            writer.write_frame("left", 0, good["rgb"], labels=good["labels"].astype(np.int32))
        with pytest.raises(ValueError, match=r"unknown camera 'top'"):
            writer.write_frame("top", 0, good["rgb"])
        with pytest.raises(IndexError, match=r"frame -1 is out of range"):
            writer.write_frame("left", -1, good["rgb"])
        writer.write_frame("left", 0, good["rgb"], labels=good["labels"].astype(np.uint8))
    assert SessionReader(url).frame(0, "left").labels.dtype == np.uint16


def test_inconsistent_sessions_are_refused(tmp_path):
    cameras = make_cameras()
    with pytest.raises(ValueError, match="undistort"):
        SessionWriter(tmp_path / "a.zarr", cameras=[Camera("d", 4, 3, np.eye(3), np.eye(3), [0, 0, 1], distortion=[0.1, 0, 0, 0])], num_frames=1, fps=1)
    with pytest.raises(ValueError, match="duplicate camera names"):
        SessionWriter(tmp_path / "a.zarr", cameras=[cameras[0], cameras[0]], num_frames=1, fps=1)
    with pytest.raises(ValueError, match=r"held-out cameras \['top'\]"):
        SessionWriter(tmp_path / "a.zarr", cameras=cameras, num_frames=1, fps=1, heldout=["top"])
    with pytest.raises(ValueError, match="cannot name a zarr group"):
        SessionWriter(tmp_path / "a.zarr", cameras=[Camera("a/b", 4, 3, np.eye(3), np.eye(3), [0, 0, 1])], num_frames=1, fps=1)
    with pytest.raises(ValueError, match="frame_times must be 4 finite seconds"):
        SessionWriter(tmp_path / "a.zarr", cameras=cameras, num_frames=4, fps=1, frame_times=[0, 1])
    # A field must cover every frame its camera has: the commit fails and leaves nothing.
    data = fields_of(cameras[0], 0)
    with pytest.raises(ValueError, match=r"camera 'left': mask is missing for 1 present frame\(s\): 1"):
        with SessionWriter(tmp_path / "a.zarr", cameras=cameras, num_frames=T, fps=1) as writer:
            writer.write_frame("left", 0, data["rgb"], mask=data["mask"])
            writer.write_frame("left", 1, data["rgb"])
    assert list(tmp_path.iterdir()) == []


def test_missing_and_foreign_sessions(tmp_path):
    with pytest.raises(FileNotFoundError, match="no session at"):
        SessionReader(tmp_path / "nothing.zarr")
    with pytest.raises(FileNotFoundError, match="no session at memory://"):
        SessionReader(f"memory://store-tests/{uuid.uuid4().hex}")
    import zarr

    zarr.open_group(str(tmp_path / "other.zarr"), mode="w")
    with pytest.raises(ValueError, match="not an mmcsplat session"):
        SessionReader(tmp_path / "other.zarr")


def test_existing_target_is_refused_and_replaced_only_at_commit(url):
    write_session(url)
    with pytest.raises(FileExistsError, match="already exists"):
        SessionWriter(url, cameras=make_cameras(), num_frames=1, fps=1.0)
    camera = make_cameras()[0]
    writer = SessionWriter(url, cameras=[camera], num_frames=1, fps=1.0, overwrite=True)
    writer.write_frame("left", 0, fields_of(camera, 9)["rgb"])
    if "://" not in url:  # a local target is replaced by a rename; until then the old session still reads
        assert SessionReader(url).camera_names == ("left", "right")
    writer.commit()
    with pytest.raises(RuntimeError, match="already committed"):
        writer.write_frame("left", 0, fields_of(camera, 9)["rgb"])
    reader = SessionReader(url)
    assert reader.camera_names == ("left",)
    np.testing.assert_array_equal(reader.frame(0, "left").rgb, fields_of(camera, 9)["rgb"])


def test_interrupted_write_leaves_nothing(url, tmp_path):
    camera = make_cameras()[0]
    with pytest.raises(RuntimeError, match="decoder died"):
        with SessionWriter(url, cameras=[camera], num_frames=T, fps=30.0) as writer:
            writer.write_frame("left", 0, fields_of(camera, 0)["rgb"])
            raise RuntimeError("decoder died")
    assert not exists(url)
    assert list(tmp_path.iterdir()) == []  # no partial directory either


def test_interrupted_replacement_keeps_the_old_local_session(tmp_path):
    url = tmp_path / "session.zarr"
    camera = write_session(url)[0]
    with pytest.raises(RuntimeError):
        with SessionWriter(url, cameras=[camera], num_frames=1, fps=1.0, overwrite=True) as writer:
            writer.write_frame("left", 0, fields_of(camera, 0)["rgb"])
            raise RuntimeError("decoder died")
    np.testing.assert_array_equal(SessionReader(url).frame(2, "left").rgb, fields_of(camera, 2)["rgb"])
    assert [path.name for path in tmp_path.iterdir()] == ["session.zarr"]


def test_a_session_whose_write_never_finished_does_not_read(url, tmp_path):
    camera = make_cameras()[0]
    writer = SessionWriter(url, cameras=[camera], num_frames=T, fps=30.0)  # killed before commit: no abort
    writer.write_frame("left", 0, fields_of(camera, 0)["rgb"])
    if "://" in url:
        with pytest.raises(IncompleteSessionError, match="never completed"):
            SessionReader(url)
        with pytest.raises(IncompleteSessionError):
            SessionUpdater(url)
    else:
        assert not exists(url)  # only the hidden partial directory exists, and it does not read either
        (partial,) = [path for path in tmp_path.iterdir() if not path.name.endswith(".lock")]  # and the writer's lock
        assert partial.name.startswith(".session.zarr.partial-")
        with pytest.raises(IncompleteSessionError, match="never completed"):
            SessionReader(partial)
    writer.abort()
    assert list(tmp_path.iterdir()) == [] and not exists(url)


def test_updater_adds_and_replaces_fields_atomically(url):
    cameras = write_session(url)
    left, right = cameras
    before = SessionReader(url)
    new_masks = {t: ~fields_of(left, t)["mask"] for t in range(T)}
    with SessionUpdater(url) as updater:
        for t in (1, 3):
            updater.write("right", "labels", t, np.full((10, 20), t, np.uint16))
        for t in range(T):
            updater.write("left", "mask", t, new_masks[t])
        # Until the commit a new reader sees the old fields only.
        during = SessionReader(url)
        assert not during.has("labels", "right")
        np.testing.assert_array_equal(during.frame(2, "left").mask, fields_of(left, 2)["mask"])
    after = SessionReader(url)
    assert after.has("labels", "right") and not before.has("labels", "right")
    assert after.frame(3, "right").labels[0, 0] == 3
    for t in range(T):
        np.testing.assert_array_equal(after.frame(t, "left").mask, new_masks[t])
        np.testing.assert_array_equal(after.frame(t, "left").labels, fields_of(left, t)["labels"])  # untouched
    import zarr

    names = {name for name, _ in zarr.open_group(url, mode="r")["cameras/left"].members()}
    assert "labels" in names and sum(name.startswith("mask.") for name in names) == 1  # one new mask array


def test_updater_keeps_the_masks_the_session_was_written_with(url):
    import zarr

    cameras = write_session(url)
    left = cameras[0]
    written = [fields_of(left, t)["mask"] for t in range(T)]
    reader = SessionReader(url)
    assert reader.has_source_mask("left") and not reader.has_source_mask("right")
    np.testing.assert_array_equal(reader.source_mask(2, "left"), written[2])
    for replacement in range(2):  # the first update keeps the written masks, the second deletes the first's
        with SessionUpdater(url) as updater:
            for t in range(T):
                updater.write("left", "mask", t, np.full((24, 32), bool(replacement)))
                updater.write("left", "labels", t, np.full((24, 32), replacement, np.uint16))
        reader = SessionReader(url)
        assert reader.frame(1, "left").mask.all() == bool(replacement)
        assert reader.frame(1, "left").labels[0, 0] == replacement
        np.testing.assert_array_equal(reader.source_mask(1, "left"), written[1])
        assert not reader.source_mask(1, "left").flags.writeable
        names = {name for name, _ in zarr.open_group(url, mode="r")["cameras/left"].members()}
        assert sorted(name.split(".")[0] for name in names) == ["depth", "labels", "mask", "mask", "present", "rgb"]
    assert zarr.open_group(url, mode="r").attrs["fields"]["left"]["source_mask"] == "mask"
    with pytest.raises(ValueError, match="camera 'right' has no masks from its capture"):
        reader.source_mask(1, "right")
    with pytest.raises(AbsentFrameError, match="frame 0 of camera 'right'"):
        reader.source_mask(0, "right")


def test_updater_failures_leave_the_session_as_it_was(url):
    cameras = write_session(url)
    left = cameras[0]
    updater = SessionUpdater(url)
    with pytest.raises(AbsentFrameError, match="frame 0 of camera 'right'"):
        updater.write("right", "mask", 0, np.zeros((10, 20), bool))
    with pytest.raises(ValueError, match=r"camera 'left' frame 0: depth must be floating-point \[24, 32\]"):
        updater.write("left", "depth", 0, np.zeros((24, 32), np.uint16))
    with pytest.raises(ValueError, match="unknown session field 'rgb'"):
        updater.write("left", "rgb", 0, np.zeros((24, 32, 3), np.uint8))
    updater.write("left", "depth", 0, np.zeros((24, 32), np.float32))
    with pytest.raises(ValueError, match=r"camera 'left': depth is missing for 3 present frame\(s\): 1, 2, 3"):
        updater.commit()
    with SessionUpdater(url) as updater:  # aborted explicitly
        for t in range(T):
            updater.write("left", "depth", t, np.zeros((24, 32), np.float32))
        updater.abort()
    reader = SessionReader(url)
    np.testing.assert_allclose(reader.frame(1, "left").depth, fields_of(left, 1)["depth"], rtol=1e-3)
    import zarr

    names = {name for name, _ in zarr.open_group(url, mode="r")["cameras/left"].members()}
    assert names == {"rgb", "present", "mask", "depth", "labels"}  # no temporary arrays left behind


def test_updater_keeps_only_the_cameras_it_is_told_recalibrated(url):
    import zarr

    left, right = write_session(url)
    moved = attrs.evolve(right, t=np.array([0.2, 0.0, 2.0]))
    with SessionUpdater(url) as updater:
        with pytest.raises(ValueError, match="no camera 'middle' to keep"):
            updater.keep_cameras([Camera("middle", 4, 4, np.eye(3), np.eye(3), [0, 0, 1.0])])
        updater.keep_cameras([moved])
        assert SessionReader(url).camera_names == ("left", "right")  # until the commit
    reader = SessionReader(url)
    assert reader.camera_names == ("right",) and reader.heldout == ("right",)
    np.testing.assert_array_equal(reader.camera("right").t, [0.2, 0.0, 2.0])
    np.testing.assert_array_equal(reader.frame(3, "right").rgb, fields_of(right, 3)["rgb"])
    group = zarr.open_group(url, mode="r")
    assert "left" not in group["cameras"] and list(group.attrs["fields"]) == ["right"]
