"""The ``mmcsplat`` console script: one sub-command per module of :mod:`mmcsplat.cli`."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from mmcsplat import __version__
from mmcsplat.plugin_api.errors import MmcsplatError

#: Sub-command name → module in mmcsplat.cli defining ``add_arguments(parser)`` and ``run(args) -> int``.
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


#: Set in the environment to see the traceback of an unexpected error instead of its one-line summary.
TRACEBACK_VARIABLE = "MMCSPLAT_TRACEBACK"


class CommandError(MmcsplatError):
    """A user-facing failure: printed as one line, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mmcsplat", description="Markerless motion capture of infants with dynamic 3D Gaussian splatting."
    )
    parser.add_argument("--version", action="version", version=f"mmcsplat {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(f"{__package__}.{module_name}")
        summary = (module.__doc__ or "").strip().split("\n")[0]
        sub = commands.add_parser(name, help=summary, description=(module.__doc__ or "").strip())
        module.add_arguments(sub)
        sub.set_defaults(_run=module.run)
    return parser


def reference_markdown() -> str:
    """The text of docs/cli.md: every command's ``--help`` at a fixed width (a test keeps the page equal
    to this; regenerate with ``python -c "from mmcsplat.cli.main import reference_markdown as r; print(r(), end='')" > docs/cli.md``)."""
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
    except MmcsplatError as error:  # every user-facing error: its message names the file, camera, frame or plugin
        print(f"mmcsplat {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # the machine's side: a permission, a full disk, a path below a file
        print(f"mmcsplat {args.command}: error: {error}", file=sys.stderr)
        return 2
    except Exception as error:
        if os.environ.get(TRACEBACK_VARIABLE):
            raise
        print(f"mmcsplat {args.command}: unexpected {type(error).__name__}: {error} "
              f"(a defect of mmcsplat or of a plugin; set {TRACEBACK_VARIABLE}=1 for the traceback)", file=sys.stderr)
        return 1

if __name__ == "__main__":
    sys.exit(main())
