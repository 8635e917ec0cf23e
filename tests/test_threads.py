"""The CPU thread policy of training: the count it chooses from the other processes' CPU use, the
MMCSPLAT_THREADS override, the CPU-time readings it works from, and the training loop using it."""

import logging

import pytest
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.training import threads
from mmcsplat.training.threads import CpuTimes, ThreadPolicy, cpu_quota, fixed_threads, others_cpus, read_cpu_times, threads_for


@pytest.mark.parametrize(
    ("ceiling", "cpus", "others", "expected"),
    [
        (2, 2, 0.0, 2),  # idle: every core
        (2, 2, 0.2, 2),  # background noise leaves the core ours
        (2, 2, 0.5, 1),  # a busy process sharing a core with one of ours (it gets half of it)
        (2, 2, 1.0, 1),  # a busy process beside our single thread
        (2, 2, 5.0, 1),  # never fewer than one
        (4, 8, 3.0, 4),  # the ceiling bounds it: 5 cores are free
        (8, 8, 2.6, 5),  # 3 cores taken
        (1, 2, 0.0, 1),  # a study worker's share of one core
    ],
)
def test_threads_follow_the_cores_others_keep_busy(ceiling, cpus, others, expected):
    assert threads_for(ceiling, cpus, others) == expected


@pytest.mark.parametrize(("value", "expected"), [(None, None), ("", None), ("auto", None), (" AUTO ", None), ("1", 1), ("3", 3)])
def test_the_override_fixes_the_count_or_leaves_the_policy(value, expected):
    assert fixed_threads(value) == expected


@pytest.mark.parametrize("value", ["0", "-2", "two", "1.5"])
def test_a_bad_override_names_the_variable(value):
    with pytest.raises(InputError, match="MMCSPLAT_THREADS"):
        fixed_threads(value)


def test_others_use_is_the_machine_time_less_our_own():
    before = CpuTimes(machine=100.0, own=10.0, wall=50.0)
    assert others_cpus(before, CpuTimes(machine=104.0, own=12.0, wall=52.0)) == pytest.approx(1.0)
    assert others_cpus(before, CpuTimes(machine=101.0, own=12.0, wall=52.0)) == 0.0  # tick rounding: never negative
    assert others_cpus(before, before) == 0.0


def test_cpu_times_are_read_from_proc_stat(tmp_path):
    stat = tmp_path / "stat"
    stat.write_text("cpu  700 100 200 5000 50 10 20 30 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n")
    ticks = threads.os.sysconf("SC_CLK_TCK")
    times = read_cpu_times(stat)
    assert times.machine == pytest.approx((700 + 100 + 200 + 10 + 20 + 30) / ticks)  # idle and iowait left out
    assert read_cpu_times(tmp_path / "absent") is None


def test_cpu_quota_from_cgroup_v2_and_v1(tmp_path):
    (tmp_path / "cpu.max").write_text("150000 100000\n")
    assert cpu_quota(tmp_path) == 1.5
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert cpu_quota(tmp_path) is None
    v1 = tmp_path / "v1"
    (v1 / "cpu").mkdir(parents=True)
    (v1 / "cpu" / "cpu.cfs_quota_us").write_text("200000\n")
    (v1 / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert cpu_quota(v1) == 2.0
    assert cpu_quota(tmp_path / "none") is None


class Machine:
    """A machine whose other processes use ``others`` CPUs while this one uses ``own``, on a clock the test moves."""

    def __init__(self):
        self.now, self.machine, self.own_total, self.others, self.own = 0.0, 0.0, 0.0, 0.0, 2.0
        self.applied = []

    def advance(self, seconds):
        self.now += seconds
        self.own_total += self.own * seconds
        self.machine += (self.own + self.others) * seconds

    def read(self):
        return CpuTimes(self.machine, self.own_total, self.now)


def policy_on(machine, fixed=None):
    return ThreadPolicy(2, 2, fixed, read=machine.read, apply=machine.applied.append, clock=lambda: machine.now)


def test_the_policy_gives_a_core_up_while_another_process_runs_and_takes_it_back():
    machine = Machine()
    policy = policy_on(machine)
    assert machine.applied == [2] and policy.threads == 2
    machine.others = 0.6  # a competitor gets its share beside our two threads
    machine.advance(0.5)
    assert policy.update() == 2  # not yet time to look again
    machine.advance(0.6)
    assert policy.update() == 1 and machine.applied[-1] == 1
    assert policy.others == pytest.approx(0.6)
    machine.own, machine.others = 1.0, 1.0  # now it has a whole core
    machine.advance(1.0)
    assert policy.update() == 1
    machine.others = 0.05  # it ended
    machine.advance(1.0)
    assert policy.update() == 2 and machine.applied[-1] == 2


def test_a_fixed_count_is_applied_once_and_never_changed():
    machine = Machine()
    policy = policy_on(machine, fixed=1)
    machine.others = 0.0
    machine.advance(5.0)
    assert policy.update() == 1 and machine.applied == [1]
    assert "fixed by MMCSPLAT_THREADS" in policy.describe()


def test_the_environment_chooses_the_policy(monkeypatch):
    monkeypatch.setenv("MMCSPLAT_THREADS", "1")
    threads_before = torch.get_num_threads()
    try:
        policy = ThreadPolicy.from_environment()
        assert policy.fixed == 1 and torch.get_num_threads() == 1
        monkeypatch.setenv("MMCSPLAT_THREADS", "auto")
        torch.set_num_threads(threads_before)
        policy = ThreadPolicy.from_environment()
        assert policy.fixed is None and policy.ceiling <= threads_before and "at most" in policy.describe()
    finally:
        threads.apply_threads(threads_before)  # numba's count too, where it is loaded


def test_the_process_policy_is_made_and_logged_once(monkeypatch, caplog):
    monkeypatch.setattr(threads, "_policy", None)
    monkeypatch.setenv("MMCSPLAT_THREADS", str(torch.get_num_threads()))
    with caplog.at_level(logging.INFO, logger="mmcsplat"):
        first = threads.thread_policy()
        assert threads.thread_policy() is first
    assert [record.getMessage() for record in caplog.records] == [first.describe()]
