"""An example third-party plugin: registers the `example-grid` initializer."""

from mmcsplat import Registration, hookimpl


@hookimpl
def mmcsplat_initializers():
    return [Registration("example-grid", "mmcsplat_example_plugin.grid:GridInitializer", "Gaussians on a regular grid")]
