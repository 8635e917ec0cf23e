"""Numeric value types of a scene, without I/O: cameras, quaternions, the rig's geometry, landmarks bound
to Gaussians, triangulation, a human skeleton's names."""
