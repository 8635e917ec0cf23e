"""List every registered plugin by kind, with its distribution and whether it is usable here; ``--show``
prints one plugin's parameters with their types, defaults and descriptions."""

from __future__ import annotations

import argparse
import inspect
import json

import attrs

from mmcsplat.cli.main import CommandError
from mmcsplat.configuration.registry import BUILTIN_DISTRIBUTION, PluginEntry, default_registry
from mmcsplat.plugin_api.kinds import KIND_NAMES
from mmcsplat.plugin_api.parameters import describe_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON")
    parser.add_argument("--show", metavar="NAME", help="print the parameters of the plugin NAME (KIND:NAME where several kinds use the name)")


def listing() -> dict:
    """The registry as plain data: plugins by kind, and broken plugin modules."""
    registry = default_registry()
    duplicates = {(e.kind, e.name) for e in registry.entries if sum(o.kind == e.kind and o.name == e.name for o in registry.entries) > 1}
    plugins = []
    for entry in registry.entries:
        reason = entry.unavailable_reason()
        if registry.shadowed(entry):
            reason = "shadowed: a built-in has this name and is used instead" + (f"; {reason}" if reason else "")
        elif (entry.kind, entry.name) in duplicates and entry.distribution != BUILTIN_DISTRIBUTION:
            reason = "name registered more than once" + (f"; {reason}" if reason else "")
        plugins.append(
            {
                "kind": entry.kind,
                "name": entry.name,
                "distribution": entry.distribution,
                "entry_point": entry.entry_point,
                "summary": entry.registration.summary,
                "available": reason is None,
                "reason": reason,
            }
        )
    broken = [{"entry_point": b.entry_point, "distribution": b.distribution, "error": b.error} for b in registry.broken]
    return {"plugins": plugins, "broken": broken}


def shown(name: str) -> list[dict]:
    """The plugins called ``name`` (``kind:name`` narrows to one kind), each with its parameters."""
    registry = default_registry()
    kind, _, plain = name.rpartition(":")
    entries = [e for e in registry.entries if e.name == plain and (not kind or e.kind == kind)]
    if not entries:
        known = ", ".join(sorted({f"{e.kind}:{e.name}" for e in registry.entries}))
        raise CommandError(f"no plugin is registered as {name!r}; registered: {known}")
    return [_description(entry) for entry in entries]


def _description(entry: PluginEntry) -> dict:
    factory = entry.load()
    rows = describe_parameters(factory)
    described = {"kind": entry.kind, "name": entry.name, "origin": entry.origin, "summary": entry.registration.summary,
                 "available": entry.unavailable_reason() is None, "declared": rows is not None}
    if rows is None:  # a plain factory: its signature is all there is to show
        rows = [{"name": p.name, "type": "" if p.annotation is inspect.Parameter.empty else str(p.annotation),
                 "default": "(required)" if p.default is inspect.Parameter.empty else repr(p.default), "doc": ""}
                for p in inspect.signature(factory).parameters.values() if p.name != "registry" and p.kind is not p.VAR_KEYWORD]
    else:
        rows = [attrs.asdict(row) for row in rows]
    return described | {"parameters": rows}


def _print_description(plugin: dict) -> None:
    print(f"{plugin['kind']} {plugin['name']!r} — {plugin['summary']}")
    print(f"  from {plugin['origin']}{'' if plugin['available'] else ' (not usable here)'}")
    if not plugin["parameters"]:
        print("  no parameters")
        return
    print("  parameters (name, default, type):" if plugin["declared"] else "  parameters (undocumented; the factory's signature):")
    width = max(len(row["name"]) for row in plugin["parameters"])
    for row in plugin["parameters"]:
        print(f"    {row['name']:<{width}}  {row['default']:<10} {row['type']}")
        if row["doc"]:
            print(f"    {'':<{width}}  {row['doc']}")


def run(args: argparse.Namespace) -> int:
    if args.show:
        plugins = shown(args.show)
        if args.json:
            print(json.dumps(plugins, indent=2))
        for plugin in [] if args.json else plugins:
            _print_description(plugin)
        return 0
    data = listing()
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    for kind in KIND_NAMES:
        rows = [p for p in data["plugins"] if p["kind"] == kind]
        print(f"{kind}:")
        if not rows:
            print("  (none)")
        for p in rows:
            state = "ok" if p["available"] else f"unavailable: {p['reason']}"
            print(f"  {p['name']:<20} {p['distribution']:<16} {state}")
            if p["summary"]:
                print(f"  {'':<20} {p['summary']}")
    for b in data["broken"]:
        print(f"broken plugin {b['entry_point']!r} from {b['distribution']}: {b['error']}")
    return 0
