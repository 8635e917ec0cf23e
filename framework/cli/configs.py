"""List the built-in configurations (usable by name wherever a configuration is asked for)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--show", metavar="NAME", help="print one configuration's TOML")


def run(args: argparse.Namespace) -> int:
    from importlib import resources

    from mmcsplat.configuration.config import builtin_config_names, load_config

    if args.show:
        load_config(args.show)  # a clear error for unknown names
        print(resources.files("mmcsplat.configuration").joinpath("configs", f"{args.show}.toml").read_text(encoding="utf-8"))
        return 0
    for name in builtin_config_names():
        text = resources.files("mmcsplat.configuration").joinpath("configs", f"{name}.toml").read_text(encoding="utf-8")
        summary = next((line[1:].strip() for line in text.splitlines() if line.startswith("#")), "")
        print(f"{name:<24} {summary}")
    return 0
