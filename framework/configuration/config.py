"""Run configurations: TOML files (or built-in names) that choose every plugin by name, with parameters.

A configuration is a TOML document. A table named after a plugin kind selects an implementation::

    [renderer]
    name = "torch-cpu"

    [[initializer]]          # kinds that compose take an array of tables
    name = "random"
    num_points = 10000

Every other key of a plugin's table is passed to its factory. Built-in configurations live in
``mmcsplat/configs/*.toml`` and are addressed by file stem; ``--set key.path=value`` overrides any value.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import attrs

from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.kinds import KIND_NAMES


class ConfigError(InputError):
    """A configuration that cannot be read or does not make sense; the message names the file and key."""


@attrs.frozen
class PluginChoice:
    """One plugin selected by a configuration: its kind, registered name and factory parameters."""

    kind: str
    name: str
    params: Mapping[str, Any] = attrs.field(factory=dict)

    def build(self, registry: Registry | None = None) -> Any:
        """Instantiate the choice through the registry."""
        return (registry or default_registry()).create(self.kind, self.name, **dict(self.params))


#: The tables of a configuration besides one per plugin kind.
SETTINGS_TABLES = ("fit",)


@attrs.frozen
class Config:
    """A loaded configuration: its source (file path or built-in name) and its values, whose top-level
    tables are ``[fit]`` and plugin kinds (anything else is a typo, refused rather than ignored)."""

    source: str
    values: Mapping[str, Any]

    def __attrs_post_init__(self) -> None:
        known = (*SETTINGS_TABLES, *KIND_NAMES)
        unknown = sorted(key for key in self.values if key not in known)
        if unknown:
            raise ConfigError(f"{self.source}: unknown table(s) {', '.join(map(repr, unknown))}; a configuration has {', '.join(known)}")

    def plugins(self, kind: str) -> list[PluginChoice]:
        """The implementations chosen for ``kind`` (empty when the configuration names none)."""
        if kind not in KIND_NAMES:
            raise ConfigError(f"{self.source}: unknown plugin kind {kind!r}")
        section = self.values.get(kind)
        if section is None:
            return []
        tables = section if isinstance(section, list) else [section]
        choices = []
        for index, table in enumerate(tables):
            where = f"{self.source}: [{kind}]" + (f" #{index + 1}" if isinstance(section, list) else "")
            if not isinstance(table, Mapping) or not isinstance(table.get("name"), str):
                raise ConfigError(f"{where} must be a table with a string 'name'")
            params = {key: value for key, value in table.items() if key != "name"}
            choices.append(PluginChoice(kind, table["name"], params))
        return choices

    def plugin(self, kind: str) -> PluginChoice:
        """The single implementation chosen for ``kind``."""
        choices = self.plugins(kind)
        if len(choices) != 1:
            raise ConfigError(f"{self.source}: expected exactly one [{kind}] table, found {len(choices)}")
        return choices[0]

    def get(self, dotted_key: str, default: Any = None) -> Any:
        """A value by dotted key (``"fit.iterations"``)."""
        node: Any = self.values
        for part in dotted_key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                return default
            node = node[part]
        return node


def builtin_config_names() -> list[str]:
    """Names of the configurations shipped with mmcsplat."""
    folder = resources.files(__package__).joinpath("configs")
    if not folder.is_dir():
        return []
    return sorted(entry.name[: -len(".toml")] for entry in folder.iterdir() if entry.name.endswith(".toml"))


def load_config(name_or_path: str | Path, overrides: Iterable[str] = ()) -> Config:
    """Load a built-in configuration by name or a TOML file by path, then apply ``key=value`` overrides."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        if path.is_dir():
            raise ConfigError(f"configuration {path} is a folder, not a TOML file: give the file (e.g. {path / 'fit.toml'})")
        if not path.is_file():
            raise ConfigError(f"configuration file {path} does not exist")
        try:
            text, source = path.read_text(encoding="utf-8"), str(path)
        except UnicodeDecodeError as error:
            raise ConfigError(f"configuration {path} is not text (a binary file?): give a TOML file ({error.reason} at byte {error.start})") from error
    else:
        resource = resources.files(__package__).joinpath("configs", f"{name_or_path}.toml")
        if not resource.is_file():
            known = ", ".join(builtin_config_names()) or "none"
            raise ConfigError(f"unknown configuration {str(name_or_path)!r}: not a file, and the built-in ones are {known}")
        text, source = resource.read_text(encoding="utf-8"), f"built-in configuration {name_or_path!r}"
    try:
        values = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{source}: invalid TOML: {error}") from error
    return Config(source, apply_overrides(values, overrides, source))


def apply_overrides(values: Mapping[str, Any], overrides: Iterable[str], source: str = "configuration") -> dict[str, Any]:
    """A copy of ``values`` with each ``dotted.key=value`` of ``overrides`` applied in turn (:func:`apply_override`)."""
    result = dict(values)
    for override in overrides:
        result = apply_override(result, override, source)
    return result


def apply_override(values: Mapping[str, Any], override: str, source: str = "configuration") -> dict[str, Any]:
    """A copy of ``values`` with one ``dotted.key=value`` override; the value is parsed as TOML when it
    can be (numbers, booleans, arrays, quoted strings) and taken as a bare string otherwise."""
    key, sep, raw = override.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"{source}: {override!r} must look like key.path=value")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return set_value(values, key, value, source)


def set_value(values: Mapping[str, Any], key: str, value: Any, source: str = "configuration") -> dict[str, Any]:
    """A copy of ``values`` with ``value`` at the dotted ``key``; missing tables are created. Inside an
    array of tables (``[[initializer]]``) a part is an index or the ``name`` of one of its tables:
    ``initializer.0.num_points`` and ``initializer.random.num_points`` reach the same value."""
    result = copy.deepcopy(dict(values))
    node: Any = result
    parts = key.split(".")
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        if isinstance(node, list):
            index = _table_index(node, part, key, source)
            if last:
                node[index] = value
            node = node[index]
            continue
        if not isinstance(node, dict):
            raise ConfigError(f"{source}: cannot set {key!r}: {parts[depth - 1]!r} is not a table")
        if last:
            node[part] = value
        else:
            node = node.setdefault(part, {})
    return result


def _table_index(tables: list, part: str, key: str, source: str) -> int:
    """The position in an array of tables that ``part`` (an index or a table's ``name``) designates."""
    if part.isdigit():
        if int(part) >= len(tables):
            raise ConfigError(f"{source}: cannot set {key!r}: index {part} is past the {len(tables)} table(s) there")
        return int(part)
    matches = [i for i, table in enumerate(tables) if isinstance(table, Mapping) and table.get("name") == part]
    if len(matches) != 1:
        names = [table.get("name") for table in tables if isinstance(table, Mapping)]
        found = "no table" if not matches else f"{len(matches)} tables"
        raise ConfigError(f"{source}: cannot set {key!r}: {found} named {part!r} there; its tables are {names}")
    return matches[0]
