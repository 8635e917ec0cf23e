"""The ``mmcsplat`` console script: one sub-command per module of :mod:`mmcsplat.cli`."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import select
import signal
import sys
import threading
import warnings

from mmcsplat import __version__
from mmcsplat.cli.options import add_output_options
from mmcsplat.plugin_api.errors import MmcsplatError

#: Sub-command name → module in mmcsplat.cli defining ``add_arguments(parser)`` and ``run(args) -> int``.
COMMANDS = {
    "demo": "demo",
    "run": "run",
    "synth": "synth",
    "ingest": "ingest",
    "plates": "plates",
    "flow": "flow",
    "segment": "segment",
    "fit": "fit",
    "track": "track",
    "landmarks": "landmarks",
    "evaluate": "evaluate",
    "compare": "compare",
    "stability": "stability",
    "render": "render",
    "export": "export",
    "view": "view",
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
        add_output_options(sub)
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


class Terminated(KeyboardInterrupt):
    """SIGTERM (what ``timeout`` and cluster schedulers send), raised where the program is, so that it
    unwinds exactly as Ctrl-C does: partial writes aborted, checkpoints kept, resumable."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def _interruption(error: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM behind ``error``: a compiled kernel (numba) interrupted mid-call surfaces as a
    ``SystemError`` whose context is the interrupt."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _log_to(verbose: bool, log_file: str | None) -> list[logging.Handler]:
    """Handlers on the ``mmcsplat`` logger for this command: the console with ``--verbose`` (warnings
    always), the file of ``--log-file``; returned so that main removes them when the command ends."""
    logger = logging.getLogger("mmcsplat")
    logger.setLevel(logging.DEBUG)
    console = logging.StreamHandler(sys.stderr)
    console.setLevel(logging.INFO if verbose else logging.WARNING)
    console.setFormatter(logging.Formatter("mmcsplat: %(message)s"))
    handlers: list[logging.Handler] = [console]
    if log_file:
        file = logging.FileHandler(log_file, encoding="utf-8")
        file.setLevel(logging.DEBUG)
        file.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        handlers.append(file)
    for handler in handlers:
        logger.addHandler(handler)
    return handlers


class OneLineWarning:
    """A :func:`warnings.formatwarning` that prints a warning as one line in mmcsplat's voice —
    ``mmcsplat COMMAND: warning: MESSAGE`` — without Python's category and source location. Only the
    text changes: the warnings stay warnings, filtered and caught (``pytest.warns``) as any other. A
    class, not a closure, so that a study's worker processes can be handed it (it pickles)."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __call__(self, message: Warning | str, category: type[Warning], filename: str, lineno: int, line: str | None = None) -> str:
        return f"mmcsplat {self.command}: warning: {' '.join(str(message).split())}\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status (2 for a user's error, 130 for Ctrl-C, 143 for SIGTERM)."""
    try:
        args = build_parser().parse_args(argv)
    except KeyboardInterrupt as interrupt:  # while the commands are still being loaded: nothing was written
        return _interrupted(interrupt)
    previous = signal.signal(signal.SIGTERM, _terminate) if threading.current_thread() is threading.main_thread() else None
    try:
        handlers = _log_to(args.verbose, args.log_file)
    except OSError as error:
        print(f"mmcsplat {args.command}: error: --log-file: {error}", file=sys.stderr)
        return 2
    previous_format, warnings.formatwarning = warnings.formatwarning, OneLineWarning(args.command)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt as interrupt:
        return _interrupted(interrupt)
    except MmcsplatError as error:  # every user-facing error: its message names the file, camera, frame or plugin
        print(f"mmcsplat {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # the machine's side: a permission, a full disk, a path below a file
        if isinstance(error, BrokenPipeError) and _reader_gone(sys.stdout):
            return _stdout_closed()
        print(f"mmcsplat {args.command}: error: {error}", file=sys.stderr)
        return 2
    except Exception as error:
        interrupt = _interruption(error)
        if interrupt is not None:
            return _interrupted(interrupt)
        if os.environ.get(TRACEBACK_VARIABLE):
            raise
        culprit = _plugin_at_fault(error)
        where = f" in {culprit}" if culprit else ""
        blame = "a defect of the plugin, or an input it does not handle" if culprit else "a defect of mmcsplat or of a plugin"
        print(f"mmcsplat {args.command}: unexpected {type(error).__name__}{where}: {error} ({blame}; set {TRACEBACK_VARIABLE}=1 for "
              "the traceback)", file=sys.stderr)
        return 1
    finally:
        _settle_zarr_io()
        warnings.formatwarning = previous_format
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        for handler in handlers:
            logging.getLogger("mmcsplat").removeHandler(handler)
            handler.close()


def _settle_zarr_io() -> None:
    """Let what zarr still reads or writes finish before the command exits (an interrupt stops the command's
    wait, not that work; a viewer stopped by Ctrl-C returns normally): else the exit prints a traceback and
    "Task was destroyed but it is pending!". A second Ctrl-C, or a wait past its bound, exits at once."""
    from mmcsplat.storage.chunks import settle_zarr_io

    with contextlib.suppress(KeyboardInterrupt, TimeoutError):
        settle_zarr_io()


def _plugin_at_fault(error: BaseException) -> str | None:
    """The registered plugin whose code raised ``error``, named (:func:`~mmcsplat.training.plugin_hooks.plugin_in_traceback`)."""
    from mmcsplat.configuration.registry import default_registry
    from mmcsplat.training.plugin_hooks import plugin_in_traceback

    try:
        return plugin_in_traceback(error, default_registry().entries)
    except Exception:  # naming the culprit must never hide the error itself
        return None


def _reader_gone(stream: object) -> bool:
    """Whether ``stream`` is a pipe whose reader has closed it (``mmcsplat plugins | head``): Linux reports
    an error condition on a pipe's write end once no reader is left."""
    try:
        fd = stream.fileno()  # type: ignore[attr-defined]
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def _stdout_closed() -> int:
    """Exit quietly when the reader of stdout went away, as a command killed by SIGPIPE would (status 141):
    stdout goes to /dev/null, so that the interpreter's flush at exit does not report it a second time."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 128 + signal.SIGPIPE


def _interrupted(interrupt: KeyboardInterrupt) -> int:
    terminated = isinstance(interrupt, Terminated)
    print(f"mmcsplat: {'terminated (SIGTERM)' if terminated else 'interrupted'}; what was complete is kept, run the command again to resume",
          file=sys.stderr)
    return 143 if terminated else 130


if __name__ == "__main__":
    sys.exit(main())
