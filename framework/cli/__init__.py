"""The ``mmcsplat`` console script: argument parsing and calls into the library, one module per command."""

from .main import main

__all__ = ["main"]
