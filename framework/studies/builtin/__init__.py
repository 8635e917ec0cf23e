"""The studies shipped with mmcsplat (``*.toml``, package data): ``mmcsplat compare NAME`` runs one by
name, with ``_`` in the file name written ``-`` (``paper_ablation.toml`` is ``paper-ablation``)."""
