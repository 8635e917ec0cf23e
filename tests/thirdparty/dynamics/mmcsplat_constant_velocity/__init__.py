"""A third-party dynamics plugin written against mmcsplat's public API only: registers ``constant-velocity``."""

from mmcsplat import Registration, hookimpl


@hookimpl
def mmcsplat_dynamics():
    return [Registration("constant-velocity", "mmcsplat_constant_velocity.method:ConstantVelocityDynamics",
                         "the subject as one rigid translation per frame, predicted at constant velocity and refined")]
