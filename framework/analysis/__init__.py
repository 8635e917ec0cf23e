"""Geometry and error analyses of runs: the masks' visual hull, drift and floaters, trajectory error."""
