"""``RUN/log.txt``: what a fit or a track did, appended by every command that works on the run, so that
a run folder carries its own history (start, settings, resumes, checkpoints, warnings, the end).

Messages go to the ``mmcsplat`` logger; :func:`run_log` adds a handler writing them to the run's file while
a step works on it. The console shows them with ``--verbose`` (cli.main).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from mmcsplat.storage.run import LOG_FILE

LOGGER = "mmcsplat"
FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


@contextmanager
def run_log(run: Path) -> Iterator[logging.Logger]:
    """The ``mmcsplat`` logger, also writing to ``run``/log.txt (appended) until the block ends."""
    logger = logging.getLogger(LOGGER)
    logger.setLevel(logging.DEBUG)
    handler = logging.FileHandler(Path(run) / LOG_FILE, encoding="utf-8")
    handler.setFormatter(logging.Formatter(FORMAT))
    handler.setLevel(logging.INFO)
    logger.addHandler(handler)
    try:
        yield logger
    finally:
        logger.removeHandler(handler)
        handler.close()
