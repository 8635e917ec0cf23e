"""Reading a session streams: peak memory does not grow with its length.

Each write and each read runs in a fresh subprocess (this file run as a script), so that its peak RSS
(``ru_maxrss``) measures that job alone. The long session decodes to over ten times what the bound allows.
"""

from __future__ import annotations

import functools
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

WIDTH, HEIGHT, CAMERAS = 256, 192, ("a", "b")
LONG, SHORT = 400, 25
CACHE_BYTES = 16 * 2**20
#: How much more the long read may peak at than the short one: a little above the cache budget (both
#: reads fill it), which is far below what holding the long session would take.
MARGIN_BYTES = 24 * 2**20


def peak_rss_bytes() -> int:
    """This process's peak resident set size (``ru_maxrss`` is KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


@functools.cache
def base_images(camera: int) -> tuple[np.ndarray, np.ndarray]:
    """A gradient texture with a little noise (compressible, not trivial), and a depth ramp."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    rng = np.random.default_rng(camera)
    rgb = np.stack([x % 256, (y + 5 * camera) % 256, (x + y) % 256], axis=-1) + rng.integers(0, 8, (HEIGHT, WIDTH, 3))
    return rgb.astype(np.uint8), (1.0 + 0.001 * x).astype(np.float32)


def synthetic_frame(t: int, camera: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``t``: the base texture moved along by 3 px per frame (cheap to make, different every frame)."""
    rgb, depth = base_images(camera)
    return np.roll(rgb, 3 * t, axis=1), depth + np.float32(0.01 * t)


def write(path: str, num_frames: int) -> dict:
    from mmcsplat.scene.camera import Camera
    from mmcsplat.storage.session import SessionWriter

    K = [[300.0, 0, WIDTH / 2 - 0.5], [0, 300.0, HEIGHT / 2 - 0.5], [0, 0, 1]]
    cameras = [Camera(name, WIDTH, HEIGHT, K, np.eye(3), [0, 0, 2.0]) for name in CAMERAS]
    start = time.perf_counter()
    with SessionWriter(path, cameras=cameras, num_frames=num_frames, fps=30.0) as writer:
        for t in range(num_frames):
            for index, name in enumerate(CAMERAS):
                rgb, depth = synthetic_frame(t, index)
                writer.write_frame(name, t, rgb, depth=depth)
    seconds = time.perf_counter() - start
    return {"frames": num_frames * len(CAMERAS), "seconds": seconds, "peak_rss": peak_rss_bytes()}


def read(path: str) -> dict:
    from mmcsplat.storage.session import SessionReader

    reader = SessionReader(path, cache_bytes=CACHE_BYTES)
    decoded = 0
    start = time.perf_counter()
    for t in range(reader.num_frames):
        for name in reader.camera_names:
            frame = reader.frame(t, name)
            decoded += frame.nbytes
            assert reader.cache.current_bytes <= CACHE_BYTES
    seconds = time.perf_counter() - start
    # The last frame's content checked, so that the loop above cannot have read nothing.
    np.testing.assert_array_equal(frame.rgb, synthetic_frame(t, len(CAMERAS) - 1)[0])
    return {"frames": reader.num_frames * len(reader.camera_names), "seconds": seconds, "decoded": decoded, "peak_rss": peak_rss_bytes()}


def run_job(job: str, path: Path, num_frames: int = 0) -> dict:
    """Run ``write`` or ``read`` in a fresh interpreter; returns its JSON report."""
    done = subprocess.run(
        [sys.executable, __file__, job, str(path), str(num_frames)], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(sys.platform == "win32", reason="ru_maxrss is POSIX")
def test_reading_a_long_session_streams(tmp_path):
    long_path, short_path = tmp_path / "long.zarr", tmp_path / "short.zarr"
    written = run_job("write", long_path, LONG)
    run_job("write", short_path, SHORT)
    short, long = run_job("read", short_path), run_job("read", long_path)

    assert long["decoded"] > 10 * MARGIN_BYTES  # holding the long session would break the bound many times over
    assert long["decoded"] > 10 * short["decoded"]
    assert long["peak_rss"] <= short["peak_rss"] + MARGIN_BYTES, (
        f"long read peaked at {long['peak_rss'] / 2**20:.0f} MiB, short at {short['peak_rss'] / 2**20:.0f} MiB"
    )
    # Writing streams too: the writer holds no frames.
    assert written["peak_rss"] <= short["peak_rss"] + 2 * MARGIN_BYTES
    print(
        f"\nwrite {written['frames'] / written['seconds']:.0f} frames/s, read {long['frames'] / long['seconds']:.0f} "
        f"frames/s ({WIDTH}×{HEIGHT} rgb + depth); peak RSS: long read {long['peak_rss'] / 2**20:.0f} MiB, "
        f"short read {short['peak_rss'] / 2**20:.0f} MiB, long write {written['peak_rss'] / 2**20:.0f} MiB; "
        f"long session decodes to {long['decoded'] / 2**20:.0f} MiB"
    )


if __name__ == "__main__":
    job, location, count = sys.argv[1], sys.argv[2], int(sys.argv[3])
    print(json.dumps(write(location, count) if job == "write" else read(location)))
