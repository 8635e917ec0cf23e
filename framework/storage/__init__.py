"""On-disk formats, each owning its schema and version: atomic writes, the session store, tracks, run
records, calibration files."""
