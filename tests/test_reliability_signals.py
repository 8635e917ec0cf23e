"""Reliability, class 5: SIGTERM (what `timeout` and schedulers send) ends a command as Ctrl-C does —
a message, exit 143, the last checkpoint kept — and the same command then resumes and says so."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from fitting_scene import write_config, write_session


def test_sigterm_during_a_fit_exits_143_and_the_fit_resumes(tmp_path):
    session = write_session(tmp_path / "s.zarr")
    config = write_config(tmp_path / "fit.toml", iterations=200, checkpoint_every=10)
    out = tmp_path / "run"
    command = [sys.executable, "-m", "mmcsplat.cli.main", "fit", str(session), "--config", str(config), "--out", str(out), "--no-progress"]
    fit = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    deadline = time.monotonic() + 120
    while not (out / "checkpoint.pt").exists() and time.monotonic() < deadline and fit.poll() is None:
        time.sleep(0.05)
    fit.send_signal(signal.SIGTERM)
    _, err = fit.communicate(timeout=120)
    assert fit.returncode == 143, err
    assert "terminated (SIGTERM)" in err and "Traceback" not in err
    stopped = json.loads((out / "run.json").read_text())
    assert stopped["status"] == "running" and stopped["iterations"] % 10 == 0 and stopped["iterations"] < 200
    assert not list(out.glob(".*.tmp")) and not (out / ".mmcsplat.lock").exists()
    # What --allow-incomplete made of the stopped fit (a render carries no label) goes when the fit resumes.
    (out / "renders").mkdir()
    (out / "renders" / "novel.mp4").write_bytes(b"the fit at its stop")

    finish = command  # the same command resumes
    done = subprocess.run(finish, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert f"resumed from iteration {stopped['iterations']}" in done.stdout
    assert json.loads((out / "run.json").read_text())["resumed_from"] == stopped["iterations"]
    assert not (out / "renders").exists()
    (out / "metrics.json").write_text("{}")  # a complete fit run again changes nothing, and keeps what was made of it
    assert subprocess.run(finish, capture_output=True, text=True, timeout=600).returncode == 0 and (out / "metrics.json").exists()


def test_a_signal_waits_until_files_written_together_are_written():
    """A checkpoint and its record are written under signals_deferred: SIGTERM sent between them is handled after both."""
    from mmcsplat.storage.atomic import signals_deferred

    events = []
    previous = signal.signal(signal.SIGTERM, lambda number, frame: events.append("signal"))
    try:
        with signals_deferred():
            events.append("checkpoint")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            events.append("record")
        time.sleep(0.05)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert events == ["checkpoint", "record", "signal"]


def test_a_compiled_kernel_interrupted_mid_call_reads_as_an_interrupt(monkeypatch, capsys):
    import mmcsplat.cli.configs as command
    from mmcsplat.cli.main import main

    def interrupted_in_numba(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as interrupt:  # numba's dispatcher then reports the pending exception so
            raise SystemError("CPUDispatcher(<function composite_forward>) returned a result with an exception set") from interrupt

    monkeypatch.setattr(command, "run", interrupted_in_numba)
    assert main(["configs"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "unexpected" not in err


#: `mmcsplat flow` with each pair of frames slowed down, so that a signal lands mid-computation.
SLOW_FLOW = ("import sys, time\n"
             "import mmcsplat.pipeline.flow as flow\n"
             "computed = flow.flow_pair\n"
             "flow.flow_pair = lambda *pair: (time.sleep(0.2), computed(*pair))[1]\n"
             "from mmcsplat.cli.main import main\n"
             "sys.exit(main(sys.argv[1:]))\n")


def test_sigterm_during_flow_leaves_no_flow_and_the_rerun_keeps_what_was_computed(tmp_path, capsys):
    from mmcsplat.cli.main import main
    from mmcsplat.pipeline.flow import flow_complete
    from mmcsplat.storage.session.flow import SessionFlow

    session = write_session(tmp_path / "s.zarr", frames=8)
    command = [sys.executable, "-c", SLOW_FLOW, "flow", str(session), "--no-progress"]
    flow = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    deadline = time.monotonic() + 120
    while not list(session.glob("flow.*/*/c.*")) and time.monotonic() < deadline and flow.poll() is None:
        time.sleep(0.05)  # until the first pair is stored
    flow.send_signal(signal.SIGTERM)
    _, err = flow.communicate(timeout=120)
    assert flow.returncode == 143, err
    assert "terminated (SIGTERM)" in err and "Traceback" not in err
    assert not SessionFlow(session).available and not flow_complete(session)  # the pending pairs are not the session's flow
    assert not list(tmp_path.glob(".*.lock"))
    assert main(["flow", str(session), "--no-progress"]) == 0
    assert "kept from an interrupted run" in capsys.readouterr().out and flow_complete(session)


def test_a_partial_store_is_removed_after_the_writes_still_in_flight(tmp_path):
    """Ctrl-C stops a wait for zarr's write, not the write, which goes on on zarr's IO thread: removing the
    partial store at once raced its last chunk (ingest ended with "Directory not empty" instead of the
    interrupt, or a chunk landed in a folder just removed). The removal now waits for those writes."""
    import asyncio

    from zarr.core.sync import _get_loop

    from mmcsplat.storage.atomic import remove_local_tree

    partial = tmp_path / ".session.zarr.partial-1"
    (partial / "cameras").mkdir(parents=True)

    async def last_chunk():  # what an interrupted write still does
        await asyncio.sleep(0.3)
        (partial / "cameras" / "c").mkdir(parents=True, exist_ok=True)
        (partial / "cameras" / "c" / "0").write_bytes(b"chunk")

    in_flight = asyncio.run_coroutine_threadsafe(last_chunk(), _get_loop())
    remove_local_tree(partial)
    in_flight.result(timeout=5)
    assert not partial.exists()


def test_a_commands_exit_waits_for_zarrs_work_in_flight(tmp_path):
    """A command that ends while zarr still reads or writes (a viewer stopped by Ctrl-C mid-read returns normally)
    lets that work finish before it exits: else the interpreter's shutdown printed a traceback and "Task was
    destroyed but it is pending!"."""
    import asyncio

    from zarr.core.sync import _get_loop

    from mmcsplat.cli.main import main

    done = []

    async def last_read():  # what a stopped command's read still does
        await asyncio.sleep(0.3)
        done.append(True)

    in_flight = asyncio.run_coroutine_threadsafe(last_read(), _get_loop())
    assert main(["plugins"]) == 0
    assert done == [True] and in_flight.done()
