"""A plugin whose hook returns names instead of Registration records: it must not break the others."""

from mmcsplat import hookimpl


@hookimpl
def mmcsplat_metrics():
    return ["psnr-but-not-a-registration"]
