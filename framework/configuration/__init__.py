"""Configurations and the plugin registry: TOML files choosing plugins by name, and the registry that finds
them through the ``mmcsplat`` entry points."""
