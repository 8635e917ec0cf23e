"""Generated sections of hand-written markdown pages (docs/performance.md, docs/results.md): each
generator owns the text between its markers and leaves the rest of the page alone."""

from __future__ import annotations

import re
from pathlib import Path

from mmcsplat.storage.atomic import write_text_atomic


def replace_section(target: Path, key: str, body: str, title: str) -> None:
    """Put ``body`` between ``<!-- KEY -->`` and ``<!-- /KEY -->`` in ``target``, replacing an earlier
    section with that key or appending one; a new page starts with ``title``. Written atomically."""
    start, end = f"<!-- {key} -->", f"<!-- /{key} -->"
    section = f"{start}\n{body.strip()}\n{end}"
    existing = target.read_text(encoding="utf-8") if target.exists() else f"{title}\n"
    pattern = re.compile(re.escape(start) + ".*?" + re.escape(end), re.DOTALL)
    if pattern.search(existing):
        text = pattern.sub(lambda _: section, existing)
    else:
        text = existing.rstrip("\n") + "\n\n" + section + "\n"
    target.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(target, text)
