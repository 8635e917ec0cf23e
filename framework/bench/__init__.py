"""The renderer benchmark on the shared scenes (docs/performance.md)."""
