"""Fetching into the download cache (mmcsplat.storage.downloads) from a server on 127.0.0.1: the checksum
is verified before anything is cached, a cached file is reused without the network, and a failed fetch
is one line naming the URL."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from local_server import closed_port, serve

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.downloads import DownloadError, cache_folder, fetch_cached, verify

CONTENT = b"a model's bytes " * 1000
DIGEST = hashlib.sha256(CONTENT).hexdigest()


def test_a_fetched_file_is_cached_under_its_checksum_and_reused_offline(tmp_path: Path) -> None:
    with serve({"/models/tiny%20model.onnx": CONTENT}) as (base, requested):
        path = fetch_cached(f"{base}/models/tiny%20model.onnx", DIGEST.upper(), cache=tmp_path)
        assert path == tmp_path / "downloads" / DIGEST / "tiny model.onnx" and path.read_bytes() == CONTENT
        assert fetch_cached(f"{base}/models/tiny%20model.onnx", DIGEST, cache=tmp_path) == path
        assert requested == ["/models/tiny%20model.onnx"]  # the second fetch read the cache
    # The server is gone: the cached copy is still found.
    assert fetch_cached(f"{base}/models/tiny%20model.onnx", DIGEST, cache=tmp_path) == path
    assert [p.name for p in tmp_path.rglob("*") if p.is_file()] == ["tiny model.onnx"]  # no temporary file left


def test_a_checksum_mismatch_is_refused_and_nothing_is_cached(tmp_path: Path) -> None:
    wrong = hashlib.sha256(b"something else").hexdigest()
    with serve({"/tiny.onnx": CONTENT}) as (base, _):
        with pytest.raises(InputError, match=f"tiny.onnx: SHA-256 {DIGEST} is not the expected {wrong}.*nothing was cached"):
            fetch_cached(f"{base}/tiny.onnx", wrong, cache=tmp_path)
    assert not list((tmp_path / "downloads").iterdir())
    with pytest.raises(InputError, match="not a SHA-256 checksum"):
        fetch_cached(f"{base}/tiny.onnx", "1234", cache=tmp_path)


def test_offline_and_missing_files_are_one_line_errors_naming_the_url(tmp_path: Path) -> None:
    url = f"http://127.0.0.1:{closed_port()}/tiny.onnx"
    with pytest.raises(DownloadError, match=f"cannot fetch {url} .*with no network here, download it on a machine that has one") as error:
        fetch_cached(url, DIGEST, cache=tmp_path, timeout=5)
    assert "\n" not in str(error.value)
    with serve({}) as (base, _), pytest.raises(DownloadError, match=f"cannot fetch {base}/gone.onnx: the server answered HTTP 404"):
        fetch_cached(f"{base}/gone.onnx", DIGEST, cache=tmp_path)
    assert not list((tmp_path / "downloads").iterdir())


def test_local_files_are_verified_and_the_cache_folder_follows_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "model.onnx"
    path.write_bytes(CONTENT)
    verify(path, DIGEST)
    with pytest.raises(InputError, match="model.onnx: SHA-256 .* is not the expected"):
        verify(path, hashlib.sha256(b"other").hexdigest())
    monkeypatch.setenv("MMCSPLAT_CACHE", str(tmp_path / "cache"))
    assert cache_folder() == tmp_path / "cache"
    monkeypatch.delenv("MMCSPLAT_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_folder() == tmp_path / "xdg" / "mmcsplat"
