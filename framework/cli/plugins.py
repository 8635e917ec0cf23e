"""List every registered plugin by kind, with its distribution and whether it is usable here."""

from __future__ import annotations

import argparse
import json

from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.kinds import KIND_NAMES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON")


def listing() -> dict:
    """The registry as plain data: plugins by kind, and broken plugin modules."""
    registry = default_registry()
    duplicates = {(e.kind, e.name) for e in registry.entries if sum(o.kind == e.kind and o.name == e.name for o in registry.entries) > 1}
    plugins = []
    for entry in registry.entries:
        reason = entry.unavailable_reason()
        if (entry.kind, entry.name) in duplicates:
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


def run(args: argparse.Namespace) -> int:
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
