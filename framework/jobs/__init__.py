"""End-to-end jobs that chain the pipeline, outputs and report: the demo on the built-in capture, and
``mmcsplat run`` on a user's own capture."""
