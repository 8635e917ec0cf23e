"""Files fetched once from an http(s) URL into a local cache, verified against their SHA-256.

A file is cached as ``CACHE/downloads/SHA256/NAME`` (``CACHE``: ``$MMCSPLAT_CACHE``, else
``$XDG_CACHE_HOME/mmcsplat``, else ``~/.cache/mmcsplat``; ``NAME`` the URL's last path segment). It is
written there atomically and only after its checksum matched, so a file in the cache is the one asked
for: a later fetch of the same checksum reads it without touching the network. A download whose checksum
differs, or one cut short, leaves nothing in the cache.
"""

from __future__ import annotations

import hashlib
import http.client
import os
import re
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import unquote, urlparse

from mmcsplat.plugin_api.errors import InputError, MmcsplatError
from mmcsplat.storage.atomic import atomic_path

CACHE_ENV = "MMCSPLAT_CACHE"
CHUNK = 1 << 20


class DownloadError(MmcsplatError, OSError):
    """A URL that could not be read (no network, no such file on the server, a timeout)."""


def is_url(location: str) -> bool:
    """Whether ``location`` is an http(s) URL rather than a local path."""
    return urlparse(location).scheme in ("http", "https")


def cache_folder() -> Path:
    """The folder downloads are cached in (module docstring)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    base = Path(os.environ["XDG_CACHE_HOME"]).expanduser() if os.environ.get("XDG_CACHE_HOME") else Path.home() / ".cache"
    return base / "mmcsplat"


def checksum(digest: str) -> str:
    """``digest`` as 64 lower-case hex digits; anything else is an error."""
    value = digest.strip().lower()
    if not re.fullmatch(r"[0-9a-f]{64}", value):
        raise InputError(f"{digest!r} is not a SHA-256 checksum (64 hex digits; `sha256sum FILE` prints one)")
    return value


def sha256_of(path: Path) -> str:
    """The SHA-256 of a file, as hex."""
    hashed = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(CHUNK):
            hashed.update(chunk)
    return hashed.hexdigest()


def verify(path: Path, digest: str) -> None:
    """Raise naming ``path`` unless its SHA-256 is ``digest``."""
    found = sha256_of(path)
    if found != checksum(digest):
        raise InputError(f"{path}: SHA-256 {found} is not the expected {checksum(digest)}: a different or damaged file")


def fetch_cached(url: str, digest: str, cache: Path | None = None, timeout: float = 60.0) -> Path:
    """The cached copy of ``url`` whose SHA-256 is ``digest``, downloaded first when the cache lacks it."""
    if not is_url(url):
        raise InputError(f"{url} is not an http(s) URL")
    digest = checksum(digest)
    name = unquote(Path(urlparse(url).path).name) or "download"
    target = (cache or cache_folder()) / "downloads" / digest / name
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(target) as partial:
            found = _download(url, partial, timeout)
            if found != digest:
                raise InputError(f"{url}: SHA-256 {found} is not the expected {digest}: the file on the server changed or the checksum "
                                 "is wrong; nothing was cached")
    except BaseException:
        if not any(target.parent.iterdir()):
            target.parent.rmdir()
        raise
    return target


def _download(url: str, path: Path, timeout: float) -> str:
    """Copy ``url`` into ``path``; returns the SHA-256 of what was read."""
    hashed = hashlib.sha256()
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response, open(path, "wb") as out:
            while chunk := response.read(CHUNK):
                hashed.update(chunk)
                out.write(chunk)
    except urllib.error.HTTPError as error:
        raise DownloadError(f"cannot fetch {url}: the server answered HTTP {error.code} {error.reason}") from None
    except (urllib.error.URLError, http.client.HTTPException, TimeoutError, ConnectionError) as error:
        reason = getattr(error, "reason", error)
        raise DownloadError(f"cannot fetch {url} ({reason}): with no network here, download it on a machine that has one and give "
                            "its local path instead") from None
    return hashed.hexdigest()
