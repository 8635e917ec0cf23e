"""The ``mmcsplat`` console script: one sub-command per module in :mod:`mmcsplat.commands`."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from . import __version__

#: Sub-command name → module in mmcsplat.commands defining ``add_arguments(parser)`` and ``run(args) -> int``.
COMMANDS = {
    "demo": "demo",
    "synth": "synth",
    "ingest": "ingest",
    "segment": "segment",
    "fit": "fit",
    "track": "track",
    "evaluate": "evaluate",
    "compare": "compare",
    "stability": "stability",
    "render": "render",
    "export": "export",
    "report": "report",
    "bench": "bench",
    "plugins": "plugins",
    "configs": "configs",
}


class CommandError(Exception):
    """A user-facing failure: printed as one line, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mmcsplat", description="Markerless motion capture of infants with dynamic 3D Gaussian splatting."
    )
    parser.add_argument("--version", action="version", version=f"mmcsplat {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(f"{__package__}.commands.{module_name}")
        summary = (module.__doc__ or "").strip().split("\n")[0]
        sub = commands.add_parser(name, help=summary, description=(module.__doc__ or "").strip())
        module.add_arguments(sub)
        sub.set_defaults(_run=module.run)
    return parser


def reference_markdown() -> str:
    """The text of docs/cli.md: every command's ``--help`` at a fixed width (a test keeps the page equal
    to this; regenerate with ``python -c "from mmcsplat.cli import reference_markdown as r; print(r(), end='')" > docs/cli.md``)."""
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal width
    try:
        parser = build_parser()
        sections = ["# Command-line reference", "", "Generated from the commands' own `--help`.", "", "```", parser.format_help().rstrip(), "```"]
        subparsers = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
        for name, sub in subparsers.choices.items():
            sections += ["", f"## mmcsplat {name}", "", "```", sub.format_help().rstrip(), "```"]
        return "\n".join(sections) + "\n"
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("mmcsplat: interrupted", file=sys.stderr)
        return 130
    except CommandError as error:
        print(f"mmcsplat {args.command}: error: {error}", file=sys.stderr)
        return 2
    except Exception as error:  # plugin, input and store errors carry clear messages of their own
        from .errors import MmcsplatError
        from .registry import PluginError

        if isinstance(error, (MmcsplatError, PluginError, ValueError, FileNotFoundError, FileExistsError, NotADirectoryError)):
            print(f"mmcsplat {args.command}: error: {error}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
