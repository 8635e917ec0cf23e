"""The shared options are spelled and read alike in every command (mmcsplat.cli.options)."""

from __future__ import annotations

import argparse

import pytest

from mmcsplat.cli.main import COMMANDS, build_parser
from mmcsplat.cli.options import comma_list, frame_range


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _options(sub: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {flag: action for action in sub._actions for flag in action.option_strings}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_shared_options_have_one_spelling(command):
    options = _options(_subcommands()[command])
    assert "--quiet" not in options and "--no-progress-bar" not in options
    assert {"--no-progress", "--verbose", "--log-file"} <= options.keys(), f"{command} lacks the shared output options"
    for flag, action in options.items():
        assert action.nargs not in ("+", "*"), f"{command} {flag}: lists are one comma-separated value (a,b), not nargs"
    if "--frames" in options:
        assert options["--frames"].type is frame_range and options["--frames"].metavar == "START:STOP[:STEP]", command
    for flag in ("--cameras", "--holdout", "--folds"):
        if flag in options:
            assert options[flag].type is comma_list and options[flag].metavar == "A,B,…", f"{command} {flag}"
    if "--set" in options:
        assert isinstance(options["--set"], argparse._AppendAction) and options["--set"].metavar == "KEY=VALUE", command
    counts = [flag for flag, action in options.items() if action.type is int and flag in ("--frames", "--cameras")]
    assert not counts, f"{command}: a count is --num-*, not {counts}"


def test_a_command_without_progress_bars_takes_no_progress(capsys):
    from mmcsplat.cli.main import main

    assert main(["configs", "--no-progress"]) == 0
    assert capsys.readouterr().out


def test_the_shared_types_read_what_they_promise():
    assert comma_list("cam_1, cam_2,") == ["cam_1", "cam_2"]
    assert frame_range("0:100:2") == slice(0, 100, 2) and frame_range(":50") == slice(None, 50, None)
    for bad in ("5", "a:b", "-1:3", "0:10:0"):
        with pytest.raises(argparse.ArgumentTypeError):
            frame_range(bad)
    with pytest.raises(argparse.ArgumentTypeError):
        comma_list(" , ")
