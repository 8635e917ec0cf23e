"""HTML building blocks of the ``mmcsplat report`` page: one file that needs nothing else — images and
videos as base64 ``data:`` URIs, the style sheet inline, no script, no network reference. Every text put
into the page goes through :func:`html.escape`."""

from __future__ import annotations

import base64
import html
import re
import shlex
from collections.abc import Callable, Sequence

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 70em; padding: 0 1em; color: #222; }
h1, h2, h3 { font-weight: 600; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
td.number { text-align: right; font-variant-numeric: tabular-nums; }
figure { display: inline-block; margin: 0.5em 1em 1em 0; vertical-align: top; }
figure img, figure video { display: block; max-width: 100%; min-width: 20em; image-rendering: pixelated; }
figure video { width: 24em; }
figcaption, .note { color: #555; font-size: 0.9em; }
.warning { background: #fff3cd; border: 1px solid #e0a800; padding: 0.5em; }
code { background: #f3f3f3; padding: 0 0.2em; }
"""


def esc(text: object) -> str:
    """``text`` as HTML text (quotes escaped too: safe in attributes)."""
    return html.escape(str(text), quote=True)


def command(*words: object) -> str:
    """A shell command line, each word quoted as needed, as escaped ``<code>``."""
    return f"<code>{esc(shlex.join(str(word) for word in words))}</code>"


def data_uri(payload: bytes, mime: str) -> str:
    """``payload`` as a base64 ``data:`` URI of type ``mime``."""
    return f"data:{mime};base64,{base64.b64encode(payload).decode('ascii')}"


def figure(content: str, caption: str | None = None) -> str:
    """A ``<figure>`` around ``content`` (HTML) with an escaped ``caption``."""
    caption_html = f"<figcaption>{esc(caption)}</figcaption>" if caption else ""
    return f"<figure>{content}{caption_html}</figure>"


def image(png: bytes, alt: str, caption: str | None = None) -> str:
    """An embedded PNG with ``alt`` text, in a figure."""
    return figure(f'<img src="{data_uri(png, "image/png")}" alt="{esc(alt)}">', caption)


def video(mp4: bytes, title: str, caption: str | None = None) -> str:
    """An embedded H.264 mp4 that loops silently, with controls, in a figure."""
    tag = f'<video src="{data_uri(mp4, "video/mp4")}" title="{esc(title)}" controls loop muted playsinline preload="metadata"></video>'
    return figure(tag, caption)


def number(value: object) -> str:
    """A metric as text: floats to 3 decimals, ``None`` as a dash."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


def table(header: Sequence[str] | None, rows: Sequence[Sequence[object]]) -> str:
    """A table of escaped cells (without a header row when ``header`` is None); numbers are formatted by
    :func:`number` and right-aligned."""
    head = f"<thead><tr>{''.join(f'<th>{esc(cell)}</th>' for cell in header)}</tr></thead>" if header is not None else ""
    body = []
    for row in rows:
        cells = [f'<td class="number">{esc(number(cell))}</td>' if isinstance(cell, (int, float)) and not isinstance(cell, bool)
                 else f"<td>{esc(number(cell))}</td>" for cell in row]
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table>{head}<tbody>{''.join(body)}</tbody></table>"


#: How every page begins: ``report --out`` replaces an existing file only when it begins so.
PAGE_START = "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>"


def page(title: str, sections: Sequence[str]) -> str:
    """The whole document: ``title`` as <title> and <h1>, then the ``sections`` (HTML)."""
    return (f"{PAGE_START}{esc(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1>{esc(title)}</h1>\n"
            + "\n".join(sections) + "\n</body>\n</html>\n")


# ------------------------------------------------------------------------------ markdown (a small subset)

_IMAGE_LINE = re.compile(r"!\[(?P<title>[^\]]*)\]\((?P<path>[^)\s]+)\)\s*$")
_CELL_SPLIT = re.compile(r"(?<!\\)\|")


def inline(text: str) -> str:
    """Escaped ``text`` with markdown's ``**bold**`` and ```code``` spans."""
    escaped = esc(text)
    escaped = re.sub(r"`([^`]+)`", r"<code>\1</code>", escaped)
    return re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", escaped)


def _cells(line: str) -> list[str]:
    return [cell.strip().replace("\\|", "|") for cell in _CELL_SPLIT.split(line.strip().strip("|"))]


def markdown_html(text: str, embed: Callable[[str, str], str]) -> str:
    """HTML of the markdown subset the study tables use — headings, pipe tables, ``-`` lists, paragraphs,
    images alone on a line — with ``embed(path, title)`` giving the HTML of each image."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].rstrip()
        if not line.strip():
            i += 1
        elif heading := re.match(r"(#{1,6})\s+(.*)", line):
            level = len(heading.group(1))
            out.append(f"<h{level}>{inline(heading.group(2))}</h{level}>")
            i += 1
        elif (picture := _IMAGE_LINE.match(line.strip())) is not None:
            out.append(embed(picture.group("path"), picture.group("title")))
            i += 1
        else:
            kind = _block_kind(line)
            block = []
            while i < len(lines) and lines[i].strip() and _block_kind(lines[i]) == kind:
                block.append(lines[i].rstrip())
                i += 1
            out.append(_block(kind, block))
    return "\n".join(out)


def _block_kind(line: str) -> str:
    if line.lstrip().startswith("|"):
        return "table"
    if line.startswith("- "):
        return "list"
    if re.match(r"#{1,6}\s", line) or _IMAGE_LINE.match(line.strip()):
        return "other"
    return "paragraph"


def _block(kind: str, block: list[str]) -> str:
    if kind == "list":
        return "<ul>" + "".join(f"<li>{inline(line[2:])}</li>" for line in block) + "</ul>"
    if kind == "paragraph":
        return f"<p>{inline(' '.join(block))}</p>"
    rows = [_cells(line) for line in block if not re.fullmatch(r"\|?[\s:|-]+\|?", line.strip())]
    header, body = rows[0], rows[1:]
    head = "".join(f"<th>{inline(cell)}</th>" for cell in header)
    cells = "".join("<tr>" + "".join(f"<td>{inline(cell)}</td>" for cell in row) + "</tr>" for row in body)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{cells}</tbody></table>"
