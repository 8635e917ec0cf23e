"""A human body by OpenPose's (and Pose2Sim's) keypoint names: the pieces that the plugins drawing,
grouping or measuring a body share, so that a renamed or added joint changes in one place."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: The limbs' long bones: upper arms, forearms, thighs, shanks.
LIMB_BONES: tuple[tuple[str, str], ...] = (
    ("LShoulder", "LElbow"), ("LElbow", "LWrist"), ("RShoulder", "RElbow"), ("RElbow", "RWrist"),
    ("LHip", "LKnee"), ("LKnee", "LAnkle"), ("RHip", "RKnee"), ("RKnee", "RAnkle"),
)
#: Each foot's points, the ankle first.
FEET: tuple[tuple[str, ...], ...] = (("LAnkle", "LHeel", "LBigToe", "LSmallToe"), ("RAnkle", "RHeel", "RBigToe", "RSmallToe"))
#: The torso's corners, in order around it (a polygon).
TORSO: tuple[str, ...] = ("LShoulder", "RShoulder", "RHip", "LHip")
#: The head's points, the one that best stands for the whole head first.
HEAD: tuple[str, ...] = ("Head", "Nose", "LEye", "REye", "LEar", "REar")


def torso_length(point: Callable[[str], np.ndarray]) -> np.ndarray:
    """Mid-shoulders to mid-hips, ``point(name)`` giving each corner's position ([..., D] arrays, any
    leading shape): the body's size that widths and reaches are taken in proportion to."""
    shoulders = (point("LShoulder") + point("RShoulder")) / 2
    hips = (point("LHip") + point("RHip")) / 2
    return np.linalg.norm(shoulders - hips, axis=-1)
