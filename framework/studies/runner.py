"""Running a study: its sessions made ready, its done cells reused, the others run by an executor — a
local process pool, the calling process (``workers=0``), or Ray tasks — and its results written.

Cells are independent and resumable, so executors only schedule them: each runs
:func:`mmcsplat.studies.cells.run_cell`, which writes everything under OUT/cells/KEY/, and the first-frame
fit that cells differing only in their dynamics share under OUT/fits/ (with Ray, OUT must be on storage
every node sees).
"""

from __future__ import annotations

import os
import shutil
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import attrs

from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.outputs.markdown_sections import replace_section
from mmcsplat.storage.atomic import signals_deferred, write_text_atomic
from mmcsplat.studies.cells import COMPLETE, FAILED, CellOutcome, run_cell
from mmcsplat.studies.results import Aggregate, Findings, Row, aggregate, build_rows, find, markdown, write_tables
from mmcsplat.studies.spec import Cell, CellSpec, Study, StudyError, expand

EXECUTORS = ("local", "ray")
CELLS_DIR, CHARTS_DIR, FITS_DIR = "cells", "charts", "fits"

#: A cell to run: its spec, its directory and the directory of shared fits.
Job = tuple[CellSpec, Path, Path]


@attrs.frozen
class StudyRun:
    """A finished pass over a study: its rows, aggregates and findings, how many cells ran now and how
    many were reused from an earlier pass, and the charts written (title, file name)."""

    study: Study
    out: Path
    rows: list[Row]
    aggregates: list[Aggregate]
    findings: Findings
    ran: int
    reused: int
    charts: list[tuple[str, str]]

    @property
    def failed(self) -> list[Row]:
        return [row for row in self.rows if row.outcome.status != COMPLETE]


def run_study(study: Study, out: str | Path, *, executor: str = "local", workers: int | None = None, retry_failed: bool = False,
              ray_address: str | None = None, progress: bool = True, registry: Registry | None = None) -> StudyRun:
    """Run every cell of ``study`` not yet done in ``out`` and write the results there.

    ``workers``: processes of the local pool (default 1; 0 runs cells in this process) or Ray tasks in
    flight (default: as many as the cluster schedules). Cells that failed before are reported again
    unless ``retry_failed``.
    """
    from tqdm import tqdm

    from mmcsplat.studies.sessions import prepare_flow, prepare_session

    if executor not in EXECUTORS:
        raise StudyError(f"unknown executor {executor!r}; executors: {', '.join(EXECUTORS)}")
    if workers is not None and (workers < 0 or (workers == 0 and executor != "local")):
        raise StudyError(f"--workers must be ≥ 1 (or 0 with the local executor: run in this process), got {workers}")
    registry = registry or default_registry()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cells = expand(study, out, registry)
    write_text_atomic(out / "study.toml", study.text)
    for plan in {cell.plan.url: cell.plan for cell in cells}.values():
        prepare_session(plan, progress)
    for plan, preset in {(cell.plan.url, cell.spec.flow): (cell.plan, cell.spec.flow) for cell in cells if cell.spec.flow}.values():
        prepare_flow(plan, preset, progress)
    _check_folds(cells)
    outcomes: dict[str, CellOutcome] = {}
    jobs: dict[str, Job] = {}
    for cell in cells:
        key = cell.spec.key
        if key in outcomes or key in jobs:
            continue  # another variant resolved to the same cell
        done = CellOutcome.read(out / CELLS_DIR / key)
        if done is not None and (done.status == COMPLETE or not retry_failed):
            outcomes[key] = done
        else:
            jobs[key] = (cell.spec, out / CELLS_DIR / key, out / FITS_DIR)
    reused = len(outcomes)
    with tqdm(total=len(jobs), desc=f"study {study.name}", unit="cell", disable=not progress) as bar:
        for outcome in _execute(executor, list(jobs.values()), workers, ray_address):
            outcomes[outcome.key] = outcome
            bar.update()
            bar.set_postfix(failed=sum(o.status != COMPLETE for o in outcomes.values()))
    return write_results(study, out, cells, outcomes, registry, ran=len(jobs), reused=reused)


def write_results(study: Study, out: Path, cells: Sequence[Cell], outcomes: dict[str, CellOutcome], registry: Registry,
                  ran: int = 0, reused: int = 0) -> StudyRun:
    """OUT/results.json, results.csv, results.md and OUT/charts/."""
    from mmcsplat.studies.charts import write_charts

    rows = build_rows(cells, outcomes, registry)
    aggregates = aggregate(rows, len(study.sessions) > 1, len({cell.backend for cell in cells}) > 1)
    findings = find(aggregates)
    charts = write_charts(out / CHARTS_DIR, rows, aggregates, findings)  # the slow part, before the tables
    text = markdown(study, rows, aggregates, findings, [(title, f"{CHARTS_DIR}/{name}") for title, name in charts])
    with signals_deferred():  # results.json, .csv and .md describe the same cells: a stop never leaves a mix
        write_tables(out, study, rows, aggregates, findings)
        write_text_atomic(out / "results.md", text)
    return StudyRun(study, out, rows, aggregates, findings, ran, reused, charts)


def publish(run: StudyRun, target: Path, command: str) -> None:
    """Put the study's section (table, findings, charts, the command that made it) into the markdown file
    ``target`` between ``<!-- study: NAME -->`` markers, replacing an earlier one and keeping the rest;
    its charts go to TARGET_FOLDER/results/NAME/."""
    name = run.study.name
    charts = target.parent / "results" / name
    charts.mkdir(parents=True, exist_ok=True)
    for _, png in run.charts:
        for suffix in (".png", ".svg"):
            shutil.copyfile(run.out / CHARTS_DIR / Path(png).with_suffix(suffix), charts / Path(png).with_suffix(suffix).name)
    body = markdown(run.study, run.rows, run.aggregates, run.findings,
                    [(title, f"results/{name}/{png}") for title, png in run.charts], heading="##")
    replace_section(target, f"study: {name}", f"{body}\nRegenerate with `{command}`.", "# Results")


def _check_folds(cells: Sequence[Cell]) -> None:
    """Every held-out camera exists in its session (checked once the sessions are ready)."""
    from mmcsplat.storage.session import SessionReader

    names: dict[str, tuple[str, ...]] = {}
    for cell in cells:
        url = cell.spec.session_url
        if cell.spec.holdout is None:
            continue
        if url not in names:
            names[url] = SessionReader(url).camera_names
        missing = [camera for camera in cell.spec.holdout if camera not in names[url]]
        if missing:
            raise StudyError(f"session {cell.session!r} ({url}) has no camera {missing[0]!r} to hold out; its cameras: {list(names[url])}")


# ----------------------------------------------------------------------------------------- executors


def _execute(executor: str, jobs: list[Job], workers: int | None, ray_address: str | None) -> Iterator[CellOutcome]:
    """Outcomes of ``jobs`` in the order they finish."""
    if not jobs:
        return
    if executor == "ray":
        yield from _ray(jobs, workers, ray_address)
    elif workers == 0:
        for spec, cell_dir, fits_dir in jobs:
            yield run_cell(spec, cell_dir, fits_dir)
    else:
        yield from _pool(jobs, workers or 1)


def _cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _start_worker(threads: int, format_warning: Callable[..., str]) -> None:
    """Each pool worker gets its share of the cores (torch and numba would each take them all), prints
    warnings as the study's process does (``format_warning``, its :func:`warnings.formatwarning`), and on
    Linux dies with the study's process: a study killed by SIGTERM would otherwise leave its workers
    running their cells, orphaned, and a restarted study would run the same cells beside them."""
    import numba
    import torch

    warnings.formatwarning = format_warning
    torch.set_num_threads(threads)
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _pool(jobs: list[Job], workers: int) -> Iterator[CellOutcome]:
    """A pool of ``workers`` spawned processes (fork would copy torch's and numba's thread pools)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_start_worker, initargs=(max(1, _cpus() // workers), warnings.formatwarning))
    try:
        futures = {pool.submit(run_cell, spec, cell_dir, fits_dir): spec for spec, cell_dir, fits_dir in jobs}
        for future in as_completed(futures):
            try:
                yield future.result()
            except BrokenProcessPool as error:  # not recorded on disk: the next pass runs the cell again
                yield CellOutcome(futures[future].key, FAILED, f"a worker process died before the cell finished (killed for memory?): {error}")
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _ray(jobs: list[Job], workers: int | None, address: str | None) -> Iterator[CellOutcome]:
    """Cells as Ray tasks of one CPU each, at most ``workers`` in flight; a Ray instance is started
    (or joined at ``address``/``RAY_ADDRESS``) unless this process is already connected to one."""
    try:
        import ray
    except ImportError as error:
        raise StudyError("the ray executor needs Ray, which is not installed here: pip install 'mmcsplat[distributed]'") from error
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False)
    task = ray.remote(num_cpus=1)(run_cell)  # a lost worker is retried: cells resume from their checkpoint
    queue, pending = list(jobs), {}
    try:
        while queue or pending:
            while queue and (workers is None or len(pending) < workers):
                spec, cell_dir, fits_dir = queue.pop(0)
                pending[task.remote(spec, str(cell_dir), str(fits_dir))] = spec
            (ready,), _ = ray.wait(list(pending), num_returns=1)
            spec = pending.pop(ready)
            try:
                yield ray.get(ready)
            except ray.exceptions.RayError as error:  # not recorded on disk: the next pass runs the cell again
                yield CellOutcome(spec.key, FAILED, f"the Ray task failed: {error}")
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()
