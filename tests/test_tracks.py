"""The tracks group: round trip, atomicity, and errors that name what is wrong."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mmcsplat.plugin_api.render_contract import Gaussians
from mmcsplat.scene.gaussian_table import GAUSSIAN_PARAMETERS
from mmcsplat.storage.tracks import TRACKS_DIR, TrackReader, TrackWriter

N, T = 7, 4


def static_params(count: int = N) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    return {
        "log_scales": torch.randn(count, 3, generator=g),
        "opacity_logits": torch.randn(count, generator=g),
        "color_logits": torch.randn(count, 3, generator=g),
        "seg_logits": torch.randn(count, 1, generator=g),
    }


def frame_params(t: int, count: int = N) -> dict[str, np.ndarray]:
    means = np.arange(count * 3, dtype=np.float32).reshape(count, 3) + t
    quats = np.tile(np.array([1.0, 0.0, 0.0, 0.1 * t], dtype=np.float32), (count, 1))
    return {"means": means, "quats": quats}


def write(run, **kwargs) -> None:
    with TrackWriter(run, num_frames=T, static=static_params(), method="test", attrs={"k": 1}, **kwargs) as writer:
        for t in range(T):
            writer.write_frame(t, **frame_params(t))


def test_round_trip(tmp_path):
    write(tmp_path)
    reader = TrackReader(tmp_path)
    assert (reader.num_frames, reader.num_gaussians, reader.method, reader.attrs) == (T, N, "test", {"k": 1})
    assert reader.dynamic == ("means", "quats") and "opacity_logits" in reader.static
    for t in (0, T - 1):
        params = reader.params(t)
        assert set(params) == set(GAUSSIAN_PARAMETERS)
        np.testing.assert_array_equal(params["means"].numpy(), frame_params(t)["means"])
        np.testing.assert_array_equal(reader.means(t), frame_params(t)["means"])
        torch.testing.assert_close(params["opacity_logits"], static_params()["opacity_logits"])
    gaussians = reader.gaussians(2)
    assert isinstance(gaussians, Gaussians) and gaussians.count == N
    torch.testing.assert_close(gaussians.colors, torch.sigmoid(static_params()["color_logits"]))
    assert not [p for p in tmp_path.iterdir() if p.name != TRACKS_DIR]  # no temporary left behind


def test_one_chunk_per_frame(tmp_path):
    write(tmp_path)
    chunks = sorted(p.name for p in (tmp_path / TRACKS_DIR / "means").iterdir() if p.name.startswith("c."))
    assert chunks == [f"c.{t}.0.0" for t in range(T)]


def test_dynamic_scales(tmp_path):
    static = {k: v for k, v in static_params().items() if k != "log_scales"}
    with TrackWriter(tmp_path, num_frames=2, static=static, method="deform") as writer:
        for t in range(2):
            writer.write_frame(t, **frame_params(t), log_scales=np.full((N, 3), float(t)))
        with pytest.raises(ValueError, match="log_scales"):
            writer.write_frame(0, **frame_params(0))
    assert TrackReader(tmp_path).params(1)["log_scales"].eq(1.0).all()


def test_nothing_visible_until_commit_and_abort_cleans_up(tmp_path):
    writer = TrackWriter(tmp_path, num_frames=T, static=static_params(), method="test")
    writer.write_frame(0, **frame_params(0))
    with pytest.raises(FileNotFoundError, match="no tracks"):
        TrackReader(tmp_path)
    with pytest.raises(ValueError, match="3 frame\\(s\\) were never written: 1, 2, 3"):
        writer.commit()
    assert list(tmp_path.iterdir()) == []

    with pytest.raises(RuntimeError), TrackWriter(tmp_path, num_frames=T, static=static_params(), method="test") as writer:
        writer.write_frame(0, **frame_params(0))
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_overwrite(tmp_path):
    write(tmp_path)
    with pytest.raises(FileExistsError, match="tracks.zarr"):
        write(tmp_path)
    static = static_params()
    static["opacity_logits"] = torch.zeros(N)
    with TrackWriter(tmp_path, num_frames=1, static=static, method="again", overwrite=True) as writer:
        writer.write_frame(0, **frame_params(5))
    reader = TrackReader(tmp_path)
    assert (reader.num_frames, reader.method) == (1, "again")
    assert sorted(p.name for p in tmp_path.iterdir()) == [TRACKS_DIR]


@pytest.mark.parametrize(
    ("static", "match"),
    [
        ({"means": torch.zeros(N, 3)}, "cannot be static"),
        ({"sh": torch.zeros(N, 3)}, "unknown static parameters"),
        ({"opacity_logits": torch.zeros(N), "color_logits": torch.zeros(N + 1, 3)}, "disagree"),
        ({"color_logits": torch.zeros(N, 4)}, r"color_logits must have shape \[7, 3\]"),
        ({"opacity_logits": torch.full((N,), float("nan"))}, "non-finite in 7"),
    ],
)
def test_bad_static(tmp_path, static, match):
    with pytest.raises(ValueError, match=match):
        TrackWriter(tmp_path, num_frames=2, static=static, method="x")
    assert list(tmp_path.iterdir()) == []


def test_bad_frames(tmp_path):
    with TrackWriter(tmp_path, num_frames=2, static=static_params(), method="x") as writer:
        with pytest.raises(IndexError, match="frame 2"):
            writer.write_frame(2, **frame_params(0))
        with pytest.raises(ValueError, match=r"frame 0: means must have shape \[7, 3\]"):
            writer.write_frame(0, means=np.zeros((N + 1, 3)), quats=frame_params(0)["quats"])
        for t in range(2):
            writer.write_frame(t, **frame_params(t))
    with pytest.raises(IndexError, match="out of range"):
        TrackReader(tmp_path).params(2)


def test_missing_run_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        TrackWriter(tmp_path / "nowhere", num_frames=1, static=static_params(), method="x")
