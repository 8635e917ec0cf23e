"""Built-in plugins: segmenters, initializers, densifiers, dynamics and metrics."""
