"""The built-in synthetic infant capture: an analytic ray-cast scene with ground truth."""
