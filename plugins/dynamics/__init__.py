"""Dynamics methods: ``iterative`` (per-frame optimisation with local rigidity, after Luiten et al. 2023)
and ``deformation`` (a deformation field over space and time, after Yang et al. 2023)."""
