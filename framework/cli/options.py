"""The options several commands share, defined once so that they are spelled and read alike everywhere:
``--no-progress``, ``--verbose`` and ``--log-file``; lists of names as one comma-separated value (``--cameras a,b``); ``--frames`` always a
range of frame indices ``START:STOP[:STEP]``; counts as ``--num-*``; ``--set KEY=VALUE`` read as TOML.
tests/test_cli_options.py walks every command's options and fails on another spelling."""

from __future__ import annotations

import argparse


def comma_list(text: str) -> list[str]:
    """``a,b`` → ``["a", "b"]`` (an argparse type)."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected comma-separated names, e.g. cam_1,cam_2")
    return names


def frame_range(text: str) -> slice:
    """``START:STOP[:STEP]`` (either end may be omitted) → a slice of frame indices (an argparse type)."""
    from mmcsplat.pipeline.ingest import parse_frames

    try:
        return parse_frames(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def scale_value(text: str) -> float | str:
    """A resize factor in (0, 1], or ``auto`` (an argparse type; :func:`mmcsplat.pipeline.image_scale.resolve_scale`)."""
    from mmcsplat.pipeline.image_scale import AUTO_SCALE, checked_scale

    word = text.strip().lower()
    try:
        return checked_scale(word if word == AUTO_SCALE else float(word))
    except ValueError:  # InputError is one
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], the share of the recorded size (0.5: half), or {AUTO_SCALE!r}; "
                                         f"got {text!r}") from None


def add_names(parser: argparse.ArgumentParser, flag: str, help: str, **kwargs) -> None:
    """A comma-separated list of names (``--cameras a,b``); repeating the option adds to the list."""
    parser.add_argument(flag, type=comma_list, action="extend", metavar="A,B,…", help=help, **kwargs)


def add_frames(parser: argparse.ArgumentParser, help: str) -> None:
    """``--frames START:STOP[:STEP]``."""
    parser.add_argument("--frames", type=frame_range, metavar="START:STOP[:STEP]", help=help)


def add_units(parser: argparse.ArgumentParser) -> None:
    """``--units {auto,m,mm}``: the calibration's length unit (:func:`mmcsplat.storage.calibration.read_rig`)."""
    from mmcsplat.storage.calibration import AUTO_UNITS, UNIT_CHOICES

    parser.add_argument("--units", choices=UNIT_CHOICES, default=AUTO_UNITS, help="length unit of the calibration's translations (default "
                        "auto: metres, or millimetres where only they put the cameras 5 cm–50 m from their centre; a Qualisys .qca.txt is "
                        "millimetres whatever this says)")


def settings_table(pairs: list[str]) -> dict:
    """The table ``--set KEY=VALUE`` options make, for a plugin's parameters (dotted keys make tables)."""
    from mmcsplat.configuration.config import apply_overrides

    return apply_overrides({}, pairs, "--set")


def add_allow_incomplete(parser: argparse.ArgumentParser) -> None:
    """``--allow-incomplete``: use an unfinished run (a fit or tracking not complete), labelling the outputs."""
    from mmcsplat.storage.completeness import ALLOW_INCOMPLETE

    parser.add_argument(ALLOW_INCOMPLETE, action="store_true",
                        help="use a run whose fit or tracking is not finished, labelling every output incomplete (refused without it)")


def add_output_options(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``, ``--verbose`` and ``--log-file``, on every command, so that a script can pass the
    same flags to each (a command with no long step shows no progress bars either way)."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars (shown by the commands with long steps)")
    parser.add_argument("--verbose", action="store_true", help="also print what the command does (its log) on the console")
    parser.add_argument("--log-file", metavar="PATH", help="append the command's full log to this file (fits and tracks also log to RUN/log.txt)")


def add_settings(parser: argparse.ArgumentParser, help: str, dest: str = "overrides", flag: str = "--set") -> None:
    """``--set KEY=VALUE`` (repeatable; the value read as TOML when it can be); a command that configures
    two plugins names the second one's ``--NAME-set``."""
    parser.add_argument(flag, dest=dest, action="append", default=[], metavar="KEY=VALUE", help=help)
