"""A plugin's failure at run time named as such: an exception other than mmcsplat's own raised inside a
plugin's hook (a renderer's ``render``, a segmenter's ``segment``, a dynamics method's ``track``) becomes one
error naming the plugin and the hook, instead of an "unexpected" error that leaves the user to guess."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from mmcsplat.plugin_api.errors import MmcsplatError, PluginError

if TYPE_CHECKING:
    from mmcsplat.configuration.registry import PluginEntry


class PluginRuntimeError(PluginError):
    """A plugin raised while it ran."""


def _interrupted(error: BaseException) -> bool:
    """Whether ``error`` stands for Ctrl-C or SIGTERM (a compiled kernel wraps the interrupt in its own error)."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


@contextmanager
def plugin_hook(kind: str, name: str, hook: str) -> Iterator[None]:
    """Run the ``hook`` of the ``kind`` plugin ``name`` in the ``with`` block; mmcsplat's own errors and
    interrupts pass unchanged."""
    try:
        yield
    except MmcsplatError:
        raise
    except Exception as error:
        if _interrupted(error):
            raise
        raise PluginRuntimeError(f"{kind} plugin {name!r} failed in {hook}(): {type(error).__name__}: {error} "
                                 "(a defect of the plugin, or an input it does not handle)") from error


def plugin_in_traceback(error: BaseException, entries: Iterable[PluginEntry]) -> str | None:
    """The registered plugin whose code raised ``error`` — the innermost frame of its traceback that lies in a
    plugin's factory module, matched by the class of its ``self`` or its function to the factory's
    attribute, else by the module (or, for a third party's, its top-level package) when that names one
    plugin — as ``"KIND plugin 'NAME' (ORIGIN)"``; None when no frame is a plugin's. Names the plugin of a
    hook that :func:`plugin_hook` does not wrap (a reader's, an initializer's, a densifier's, a landmark source's)."""
    entries = list(entries)
    by_attribute = {tuple(entry.registration.factory.split(":", 1)): entry for entry in entries}
    by_module: dict[str, list[PluginEntry]] = {}
    for entry in entries:
        module = entry.registration.factory.split(":", 1)[0]
        by_module.setdefault(module, []).append(entry)
        if "." in module and not module.startswith("mmcsplat."):
            by_module.setdefault(module.split(".")[0], []).append(entry)
    frames = []
    trace = error.__traceback__
    while trace is not None:
        frames.append(trace.tb_frame)
        trace = trace.tb_next
    for frame in reversed(frames):
        module = frame.f_globals.get("__name__", "")
        owner = frame.f_locals.get("self")
        found = [by_attribute[key] for key in ((module, type(owner).__name__), (module, frame.f_code.co_name)) if key in by_attribute]
        candidates = found or by_module.get(module) or by_module.get(module.split(".")[0], [])
        if len(candidates) == 1 or found:
            entry = candidates[0]
            return f"{entry.kind} plugin {entry.name!r} ({entry.origin})"
    return None
