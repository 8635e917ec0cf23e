"""The plugin registry: discovers plugin modules through the ``mmcsplat`` entry-point group and resolves
implementations by kind and name.

Built-in implementations register exactly as a third-party package does, through entry points in the
distribution's metadata. One plugin that fails to import, or whose hook raises, is recorded as broken and
reported; it never hides the others.
"""

from __future__ import annotations

import importlib
import inspect
import warnings
from collections.abc import Callable, Iterable, Mapping
from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import attrs
import pluggy

from mmcsplat.plugin_api import hookspecs
from mmcsplat.plugin_api.errors import (
    BrokenPluginError,
    DuplicatePluginError,
    MmcsplatError,
    PluginError,
    PluginUnavailableError,
    UnknownPluginError,
)
from mmcsplat.plugin_api.kinds import KIND_NAMES, KINDS
from mmcsplat.plugin_api.parameters import REGISTRY_PARAMETER, build_from_table, checked_table
from mmcsplat.plugin_api.registration import Registration

ENTRY_POINT_GROUP = "mmcsplat"
#: The distribution of the built-in plugins, which win a name clash with a third-party one.
BUILTIN_DISTRIBUTION = "mmcsplat"


@attrs.frozen
class PluginEntry:
    """One registered implementation, with the distribution and entry point it came from."""

    kind: str
    name: str
    distribution: str
    entry_point: str
    registration: Registration

    @property
    def origin(self) -> str:
        return f"entry point {self.entry_point!r} of distribution {self.distribution!r}"

    def unavailable_reason(self) -> str | None:
        """``None`` when usable here, otherwise why not."""
        check = self.registration.unavailable
        if check is None:
            return None
        try:
            return check()
        except Exception as error:  # a faulty check must not break the listing
            return f"availability check failed: {error!r}"

    def load(self) -> Callable[..., Any]:
        """Import the factory."""
        module_name, _, attribute = self.registration.factory.partition(":")
        try:
            target: Any = importlib.import_module(module_name)
            for part in attribute.split("."):
                target = getattr(target, part)
        except Exception as error:
            raise BrokenPluginError(
                f"{self.kind} {self.name!r} from {self.origin} failed to load {self.registration.factory!r}: {error!r}"
            ) from error
        return target


@attrs.frozen
class BrokenPlugin:
    """A plugin module that could not be imported or whose hook raised."""

    entry_point: str
    distribution: str
    error: str


def _distribution_of(entry_point: EntryPoint) -> str:
    dist = getattr(entry_point, "dist", None)
    return dist.name if dist is not None else "<unknown distribution>"


class Registry:
    """Every implementation registered through the ``mmcsplat`` entry points (or passed in directly)."""

    def __init__(self, plugin_modules: Iterable[tuple[str, str, object]] | None = None) -> None:
        """Discover entry points; ``plugin_modules`` adds (entry-point name, distribution, module) triples,
        for tests and for applications that embed mmcsplat."""
        self._manager = pluggy.PluginManager(hookspecs.PROJECT)
        self._manager.add_hookspecs(hookspecs)
        self.broken: list[BrokenPlugin] = []
        origins: dict[str, tuple[str, str]] = {}
        for ep_name, distribution, module in self._discover(plugin_modules):
            key = f"{distribution}:{ep_name}"
            try:
                self._manager.register(module, name=key)
            except Exception as error:
                self.broken.append(BrokenPlugin(ep_name, distribution, f"invalid plugin module: {error}"))
                continue
            origins[key] = (ep_name, distribution)
        self.entries: list[PluginEntry] = []
        for kind in KINDS:
            hook_name = kind.hook
            for impl in getattr(self._manager.hook, hook_name).get_hookimpls():
                ep_name, distribution = origins[impl.plugin_name]
                try:
                    registrations = list(impl.function() or [])
                except Exception as error:
                    self.broken.append(BrokenPlugin(ep_name, distribution, f"hook {hook_name} raised {error!r}"))
                    continue
                wrong = [item for item in registrations if not isinstance(item, Registration)]
                if wrong:
                    self.broken.append(BrokenPlugin(ep_name, distribution, f"hook {hook_name} returned {wrong[0]!r}, not Registration records"))
                    continue
                for registration in registrations:
                    self.entries.append(PluginEntry(kind.name, registration.name, distribution, ep_name, registration))
        self.entries.sort(key=lambda entry: (KIND_NAMES.index(entry.kind), entry.name, entry.distribution))

    def _discover(self, extra: Iterable[tuple[str, str, object]] | None) -> Iterable[tuple[str, str, object]]:
        for entry_point in entry_points(group=ENTRY_POINT_GROUP):
            distribution = _distribution_of(entry_point)
            try:
                module = entry_point.load()
            except Exception as error:
                self.broken.append(BrokenPlugin(entry_point.name, distribution, f"import failed: {error!r}"))
                continue
            yield entry_point.name, distribution, module
        yield from extra or ()

    def names(self, kind: str) -> list[str]:
        """The registered names of one kind, sorted."""
        _check_kind(kind)
        return sorted({entry.name for entry in self.entries if entry.kind == kind})

    def get(self, kind: str, name: str) -> PluginEntry:
        """The entry registered as ``name``; a clear error when unknown or registered twice."""
        _check_kind(kind)
        matches = [entry for entry in self.entries if entry.kind == kind and entry.name == name]
        if not matches:
            known = ", ".join(self.names(kind)) or "none"
            hint = "".join(f"\n  broken plugin {b.entry_point!r} ({b.distribution}): {b.error}" for b in self.broken)
            raise UnknownPluginError(f"unknown {kind} {name!r}; registered: {known}{hint}")
        builtin = [entry for entry in matches if entry.distribution == BUILTIN_DISTRIBUTION]
        if len(matches) > 1 and len(builtin) == 1:
            others = "; ".join(entry.origin for entry in matches if entry is not builtin[0])
            warnings.warn(f"{kind} {name!r} is also registered by {others}: the built-in is used (rename the other to use it)", stacklevel=2)
            return builtin[0]
        if len(matches) > 1:
            origins = "; ".join(entry.origin for entry in matches)
            raise DuplicatePluginError(f"{kind} {name!r} is registered more than once: {origins}")
        return matches[0]

    def shadowed(self, entry: PluginEntry) -> bool:
        """Whether ``entry`` is a third-party plugin under a built-in's name (the built-in is used)."""
        return entry.distribution != BUILTIN_DISTRIBUTION and any(
            other.distribution == BUILTIN_DISTRIBUTION and other.kind == entry.kind and other.name == entry.name for other in self.entries)

    def check_parameters(self, kind: str, name: str, params: Mapping[str, Any]) -> None:
        """The configuration's parameters of ``name`` checked against its fields without building it (as
        :meth:`create` checks them), so that a misspelt key fails before anything runs; a plugin not usable
        here is left to :meth:`create` to refuse."""
        entry = self.get(kind, name)
        if entry.unavailable_reason():
            return
        factory = entry.load()
        if isinstance(factory, type) and attrs.has(factory):
            injected = (REGISTRY_PARAMETER,) if REGISTRY_PARAMETER in inspect.signature(factory).parameters else ()
            checked_table(factory, params, f"{kind} {name!r}", injected)

    def create(self, kind: str, name: str, **params: Any) -> Any:
        """Build the implementation ``name`` of ``kind`` with the configuration's parameters (checked
        against its fields when the factory is an attrs class, :mod:`mmcsplat.plugin_api.parameters`). A factory
        that declares a ``registry`` parameter gets this registry, to build the plugins it names (the
        ``depth-supervised`` initializer's depth source) where its own caller's plugins are."""
        entry = self.get(kind, name)
        reason = entry.unavailable_reason()
        if reason:
            raise PluginUnavailableError(f"{kind} {name!r} from {entry.origin} is not usable here: {reason}")
        if REGISTRY_PARAMETER in params:
            raise PluginError(f"{kind} {name!r}: 'registry' is not a configuration parameter (the registry passes itself)")
        factory = entry.load()
        injected = {REGISTRY_PARAMETER: self} if REGISTRY_PARAMETER in inspect.signature(factory).parameters else {}
        try:
            return build_from_table(factory, params, f"{kind} {name!r}", **injected)
        except MmcsplatError:  # already names the plugin (its parameters) or the input at fault
            raise
        except TypeError as error:
            raise PluginError(f"{kind} {name!r} from {entry.origin} rejected its parameters {sorted(params)}: {error}") from error
        except Exception as error:  # a plugin's constructor failing must name the plugin, not look like mmcsplat's defect
            raise PluginError(f"{kind} {name!r} from {entry.origin} failed to build: {error!r}") from error


def _check_kind(kind: str) -> None:
    if kind not in KIND_NAMES:
        raise PluginError(f"unknown plugin kind {kind!r}; kinds are {', '.join(KIND_NAMES)}")


@cache
def default_registry() -> Registry:
    """The process-wide registry, discovered once."""
    return Registry()
