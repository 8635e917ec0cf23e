"""What a plugin hook returns for one implementation, and the availability check most plugins need.

A leaf module: the hook specifications, the registry and every plugin import it, and it imports nothing
of mmcsplat.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from typing import Any, Protocol

import attrs


def needs_modules(*modules: str, extra: str | None = None) -> Callable[[], str | None]:
    """An availability check: the reason the implementation cannot run when a module is missing, with the
    package ``extra`` that installs it when there is one."""

    def check() -> str | None:
        missing = [module for module in modules if importlib.util.find_spec(module) is None]
        if not missing:
            return None
        return f"needs {', '.join(missing)} (not installed)" + (f": pip install 'mmcsplat[{extra}]'" if extra else "")

    return check


@attrs.frozen
class Registration:
    """What a plugin hook returns for one implementation.

    ``factory`` is ``"module:attribute"``; the attribute is called with the configuration's parameters to
    build an instance. ``unavailable`` returns ``None`` when the implementation can run here, otherwise the
    reason it cannot (e.g. "no CUDA device").
    """

    name: str
    factory: str
    summary: str = ""
    unavailable: Callable[[], str | None] | None = None

    def __attrs_post_init__(self) -> None:
        if ":" not in self.factory:
            raise ValueError(f"registration {self.name!r}: factory must be 'module:attribute', got {self.factory!r}")


class PluginBuilder(Protocol):
    """What a factory that builds other plugins by name receives as its ``registry`` parameter (the
    registry building it passes itself): a plugin of ``kind`` registered as ``name``, built with ``params``."""

    def create(self, kind: str, name: str, **params: Any) -> Any:
        """Build the implementation ``name`` of ``kind``."""
