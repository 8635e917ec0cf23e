"""mmcsplat: markerless motion capture of infants with dynamic 3D Gaussian splatting.

The core package: plugin interfaces (:mod:`mmcsplat.interfaces`), the registry (:mod:`mmcsplat.registry`),
the hook specifications plugins implement (:mod:`mmcsplat.hookspecs`), cameras, the session store and the CLI.
Concrete implementations live in :mod:`mmcsplat.backends`, :mod:`mmcsplat.plugins` and
:mod:`mmcsplat.datasets` and are reached only through the registry.
"""

from .hookspecs import hookimpl
from .registry import Registration, default_registry, needs_modules

__version__ = "0.1.0"

__all__ = ["Registration", "__version__", "default_registry", "hookimpl", "needs_modules"]
