"""The base of mmcsplat's user-facing errors: the CLI prints their message and exits with status 2."""


class MmcsplatError(Exception):
    """An error whose message tells the user what is wrong and where (file, camera, frame, plugin)."""
