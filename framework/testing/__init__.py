"""Reusable test suites that hold an implementation to its contract; a third-party plugin runs them
against itself (see :mod:`mmcsplat.testing.renderer_contract`). Importing them needs pytest."""
