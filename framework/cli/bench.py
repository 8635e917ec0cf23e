"""Time renderer backends (forward + backward) on the benchmark scenes of ../shared/bench/README.md.

Scene D, mmcsplat's own (a real capture's first-frame fit), runs when named. Each backend runs once as warm-up (compilation included, reported apart), then --repeats timed runs,
interleaved between backends so that speed-ups (against torch-reference) compare runs under the same
machine load. Prints a table, or JSON with --json; --write puts the markdown report into its section of a page (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mmcsplat.cli.main import CommandError
from mmcsplat.cli.options import comma_list
from mmcsplat.configuration.registry import default_registry
from mmcsplat.outputs.markdown_sections import replace_section

SCENES = ("A", "B", "C", "D")
DEFAULT_SCENES = ("A", "B", "C")  # D takes torch-reference minutes per run: it runs when named


def _scenes(text: str) -> list[str]:
    scenes = comma_list(text)
    unknown = [scene for scene in scenes if scene not in SCENES]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown scene(s) {', '.join(unknown)}; the scenes are {', '.join(SCENES)}")
    return scenes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", action="extend", type=_scenes, metavar="A,B,…",
                        help="scenes to run (default: A,B,C; D, a real capture's first-frame fit, when named)")
    parser.add_argument("--backend", action="extend", type=comma_list, metavar="A,B,…",
                        help="renderer backends to time (default: every available one)")
    parser.add_argument("--repeats", type=int, default=7, help="timed runs per backend and scene (default 7)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--write", type=Path, metavar="PATH", help="put the markdown report into its section of this page")


def _renderers(names: list[str] | None) -> dict:
    registry = default_registry()
    if names is None:
        names = []
        for name in registry.names("renderer"):
            reason = registry.get("renderer", name).unavailable_reason()
            if reason:
                print(f"skipping renderer {name!r}: {reason}", file=sys.stderr)
            else:
                names.append(name)
    return {name: registry.create("renderer", name) for name in dict.fromkeys(names)}


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from mmcsplat.bench.benchmark import run_benchmark, to_json, to_markdown

    if args.repeats < 1:
        raise CommandError(f"--repeats must be at least 1, got {args.repeats}")
    renderers = _renderers(args.backend)
    if not renderers:
        raise CommandError("no renderer backend is available")
    scenes = list(dict.fromkeys(args.scene or DEFAULT_SCENES))
    with tqdm(desc="bench", unit="step", disable=args.json or args.no_progress, file=sys.stderr) as bar:
        def progress(message: str) -> None:
            bar.set_postfix_str(message)
            bar.update()

        report = run_benchmark(scenes, renderers, repeats=args.repeats, progress=progress)
    markdown = to_markdown(report)
    if args.write:  # the bench owns its section of the page; other sections are left as they are
        replace_section(args.write, "bench", markdown, "# Performance")
    print(json.dumps(to_json(report), indent=2) if args.json else markdown)
    return 0
