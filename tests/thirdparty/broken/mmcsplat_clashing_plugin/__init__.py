"""A plugin that registers a metric under a name mmcsplat already uses."""

from mmcsplat import Registration, hookimpl


@hookimpl
def mmcsplat_metrics():
    return [Registration("psnr", "mmcsplat_clashing_plugin:Nothing")]
