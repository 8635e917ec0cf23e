"""Dataset readers and writers, calibration files and the synthetic infant capture."""
