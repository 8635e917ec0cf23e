"""Studies: specifications, cells, the runner, results, charts and stability runs."""
