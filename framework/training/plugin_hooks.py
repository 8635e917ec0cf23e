"""A plugin's failure at run time named as such: an exception other than mmcsplat's own raised inside a
plugin's hook (a renderer's ``render``, a segmenter's ``segment``, a dynamics method's ``track``) becomes one
error naming the plugin and the hook, instead of an "unexpected" error that leaves the user to guess."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from mmcsplat.plugin_api.errors import MmcsplatError, PluginError


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
