"""mmcsplat: markerless motion capture of infants with dynamic 3D Gaussian splatting.

The core package, in rooms by layer (docs/architecture.md): :mod:`mmcsplat.plugin_api` (all a plugin may
import, with :mod:`mmcsplat.scene`, :mod:`mmcsplat.storage` and :mod:`mmcsplat.training`),
:mod:`mmcsplat.configuration` (configurations and the plugin registry), :mod:`mmcsplat.pipeline` (one
module per step of the data flow), :mod:`mmcsplat.analysis`, :mod:`mmcsplat.outputs`,
:mod:`mmcsplat.studies`, :mod:`mmcsplat.bench`, :mod:`mmcsplat.synthetic`, :mod:`mmcsplat.jobs` and
:mod:`mmcsplat.cli`. Concrete implementations live in :mod:`mmcsplat.backends`, :mod:`mmcsplat.plugins`
and :mod:`mmcsplat.datasets` and are reached only through the registry.
"""

import os

# The CPU kernels run on numba's OpenMP threads (libgomp, as torch's own). Their wait policy is left to
# the environment: libgomp's default spins briefly before sleeping, which the demo needs (passive
# waiting made it 1.6× slower on an idle machine, 377 s against 235 s); on a machine shared with other
# CPU-heavy work, training leaves the busy cores to it instead (mmcsplat.training.threads;
# docs/performance.md, "Threads").
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

from .plugin_api.hookspecs import hookimpl  # noqa: E402
from .plugin_api.registration import Registration, needs_modules  # noqa: E402

__version__ = "0.1.0"

__all__ = ["Registration", "__version__", "hookimpl", "needs_modules"]
