"""Built-in renderer backends."""
