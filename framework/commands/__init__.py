"""Sub-commands of the mmcsplat console script."""
