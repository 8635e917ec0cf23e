"""How many CPU threads training uses: the cores the other processes leave free, re-chosen as it trains.

torch's and numba's OpenMP threads (libgomp) spin briefly at every barrier, which gives an idle machine
its full speed but collapses when another CPU-bound process shares the cores: one thread is descheduled
and the others spin waiting for it (issue 27: 1.9 s per iteration instead of 0.06 s; two threads 2.2×
slower than one beside a single busy process). Passive waiting avoids the collapse but costs the idle
demo 1.6× (docs/performance.md, "Threads"). So the spinning stays, and the thread count follows the load:
every :data:`RECHECK_S` seconds :class:`ThreadPolicy` reads the CPU time the whole machine spent
(/proc/stat) less its own process's, and leaves out each core the other processes kept busy for more
than :data:`BUSY_SHARE` of the time. Niced work takes little from a normal-priority fit, so it takes few
cores from it here too.

``MMCSPLAT_THREADS=N`` fixes N threads instead (no re-choosing; results then never depend on the load);
``auto``, the default, is the policy. The process's torch thread count (``OMP_NUM_THREADS``, a study
worker's share) and its CPU quota (cgroup ``cpu.max``) stay the ceiling.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import attrs
import torch

from mmcsplat.plugin_api.errors import InputError

ENVIRONMENT = "MMCSPLAT_THREADS"
AUTO = "auto"
RECHECK_S = 1.0  # seconds between choices: /proc/stat's 100 Hz ticks give ±0.02 of a core over this window
# A core the other processes use for more than this share of the time is theirs. Well below a half: a busy
# process beside our two spinning threads on two cores gets only a half to two thirds of one (fair shares).
BUSY_SHARE = 0.25

logger = logging.getLogger(__name__)


def threads_for(ceiling: int, cpus: int, others: float) -> int:
    """Threads to use on a machine of ``cpus`` CPUs whose other processes used ``others`` CPUs' worth of
    time: each core they use beyond :data:`BUSY_SHARE` of is left to them; at least 1, at most ``ceiling``."""
    taken = max(0, math.ceil(others - BUSY_SHARE))
    return max(1, min(ceiling, cpus - taken))


def fixed_threads(value: str | None) -> int | None:
    """The ``MMCSPLAT_THREADS`` setting: ``None`` for the policy (unset, empty or ``auto``), else its count."""
    if value is None or value.strip().lower() in ("", AUTO):
        return None
    try:
        count = int(value)
    except ValueError:
        count = 0
    if count < 1:
        raise InputError(f"{ENVIRONMENT}={value!r}: set it to a thread count of at least 1, or to {AUTO!r} to follow the machine's load")
    return count


@attrs.frozen
class CpuTimes:
    """Cumulative CPU seconds: ``machine`` (every CPU's non-idle time, steal included), ``own`` (this
    process), read at ``wall`` (a monotonic clock)."""

    machine: float
    own: float
    wall: float


def read_cpu_times(stat: Path = Path("/proc/stat")) -> CpuTimes | None:
    """The machine's and this process's CPU time now; ``None`` where /proc/stat does not exist."""
    try:
        fields = stat.read_text().split("\n", 1)[0].split()
    except OSError:
        return None
    # cpu user nice system idle iowait irq softirq steal (guest time is counted in user already)
    ticks = [int(value) for value in fields[1:9]]
    busy = sum(ticks) - ticks[3] - ticks[4]
    return CpuTimes(busy / os.sysconf("SC_CLK_TCK"), time.process_time(), time.monotonic())


def others_cpus(before: CpuTimes, after: CpuTimes) -> float:
    """CPUs' worth of time the other processes used between two readings."""
    elapsed = after.wall - before.wall
    if elapsed <= 0:
        return 0.0
    return max(0.0, ((after.machine - before.machine) - (after.own - before.own)) / elapsed)


def machine_cpus() -> int:
    """CPUs of the machine (those /proc/stat adds up), not only those this process may use."""
    return os.cpu_count() or 1


def cpu_quota(cgroup: Path = Path("/sys/fs/cgroup")) -> float | None:
    """CPUs' worth of time this process's cgroup may use (v2 ``cpu.max`` or v1 ``cpu.cfs_quota_us``), or ``None``."""
    try:
        quota, period = (cgroup / "cpu.max").read_text().split()[:2]
    except (OSError, ValueError):
        try:
            quota = (cgroup / "cpu" / "cpu.cfs_quota_us").read_text().strip()
            period = (cgroup / "cpu" / "cpu.cfs_period_us").read_text().strip()
        except OSError:
            return None
    if quota in ("max", "-1"):
        return None
    return int(quota) / int(period)


def ceiling_threads() -> int:
    """The most threads the policy uses: torch's count at start, within the CPUs this process may run on
    (affinity) and its quota."""
    ceiling = torch.get_num_threads()
    if hasattr(os, "sched_getaffinity"):
        ceiling = min(ceiling, len(os.sched_getaffinity(0)))
    quota = cpu_quota()
    if quota is not None:
        ceiling = min(ceiling, max(1, math.floor(quota)))
    return max(1, ceiling)


def apply_threads(count: int) -> None:
    """Run torch's and (once loaded) numba's kernels on ``count`` threads, numba within its pool's size."""
    if torch.get_num_threads() != count:
        torch.set_num_threads(count)
    numba = sys.modules.get("numba")
    if numba is not None:
        wanted = min(count, numba.config.NUMBA_NUM_THREADS)
        if numba.get_num_threads() != wanted:
            numba.set_num_threads(wanted)


class ThreadPolicy:
    """Chooses and applies the thread count (module docstring). :meth:`update` is cheap enough for every
    training step; it re-chooses once :data:`RECHECK_S` seconds have passed since the last choice.

    ``fixed`` pins the count; ``read``, ``apply`` and ``clock`` are the CPU-time reading, the setter and
    the clock of ``read``'s ``wall`` (tests swap them)."""

    def __init__(
        self,
        ceiling: int,
        cpus: int,
        fixed: int | None = None,
        read: Callable[[], CpuTimes | None] = read_cpu_times,
        apply: Callable[[int], None] = apply_threads,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.ceiling, self.cpus, self.fixed = ceiling, cpus, fixed
        self._read, self._apply, self._clock = read, apply, clock
        self.threads = fixed if fixed is not None else ceiling
        self.others = 0.0
        self._last = None if fixed is not None else read()
        apply(self.threads)

    @classmethod
    def from_environment(cls) -> ThreadPolicy:
        """The policy ``MMCSPLAT_THREADS`` asks for, on this machine."""
        return cls(ceiling_threads(), machine_cpus(), fixed_threads(os.environ.get(ENVIRONMENT)))

    def describe(self) -> str:
        """One line for the run's log."""
        if self.fixed is not None:
            return f"CPU threads: {self.fixed}, fixed by {ENVIRONMENT}"
        return (f"CPU threads: at most {self.ceiling} of {self.cpus} CPUs, fewer while other processes keep cores busy "
                f"(re-chosen every {RECHECK_S:g} s; {ENVIRONMENT}=N fixes N)")

    def update(self) -> int:
        """The thread count in force, re-chosen and applied when its time has come."""
        if self._last is None or self._clock() - self._last.wall < RECHECK_S:
            return self.threads
        now = self._read()
        if now is None:
            return self.threads
        self.others = others_cpus(self._last, now)
        self._last = now
        chosen = threads_for(self.ceiling, self.cpus, self.others)
        if chosen != self.threads:
            logger.debug("CPU threads %d → %d: other processes used %.2f CPUs", self.threads, chosen, self.others)
            self.threads = chosen
        self._apply(chosen)  # also reaches numba when it was loaded after the last choice
        return chosen


_policy: ThreadPolicy | None = None


def thread_policy() -> ThreadPolicy:
    """This process's policy, made from the environment and logged on first use."""
    global _policy
    if _policy is None:
        _policy = ThreadPolicy.from_environment()
        logger.info(_policy.describe())
    return _policy
