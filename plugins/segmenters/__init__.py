"""Built-in segmenters: subject masks (and semantic labels) for the frames of a session.

Each segmenter produces raw masks; :mod:`.postprocess` applies the clean-up they share (largest connected
component, dilation). The ``mmcsplat segment`` command writes their output into the session.
"""
