"""A human body by OpenPose's (and Pose2Sim's) keypoint names: the pieces that the plugins drawing,
grouping or measuring a body share, so that a renamed or added joint changes in one place."""

from __future__ import annotations

from collections.abc import Callable, Mapping

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
#: The synthetic infant's names of the torso's corners (``mmcsplat synth``'s joints), in :data:`TORSO`'s order.
SYNTHETIC_TORSO: tuple[str, ...] = ("shoulder_left", "shoulder_right", "hip_right", "hip_left")
#: The torso's corners by each naming a body's joints come in.
TORSO_NAMINGS: tuple[tuple[str, ...], ...] = (TORSO, SYNTHETIC_TORSO)
#: The head's points, the one that best stands for the whole head first.
HEAD: tuple[str, ...] = ("Head", "Nose", "LEye", "REye", "LEar", "REar")


#: Joints of OpenPose's that MediaPipe's and COCO's keypoints lack, each at the midpoint of two they have: the
#: neck between the shoulders, the head's centre between the ears. Without a neck the torso and the head are not
#: joined (the masks' neck, the body parts' neck part: docs/results.md, "The neck").
MIDPOINTS: dict[str, tuple[str, str]] = {"Neck": ("LShoulder", "RShoulder"), "Head": ("LEar", "REar")}


def with_midpoints(joints: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``joints`` (name → position, any shape) with each of :data:`MIDPOINTS` they lack but have both ends of."""
    added = {name: (joints[a] + joints[b]) / 2 for name, (a, b) in MIDPOINTS.items() if name not in joints and a in joints and b in joints}
    return {**joints, **added}


#: Joints OpenPose names too, by the part of a MediaPipe, COCO or Halpe name after its side (``left_knee``).
_SIDED = {"eye": "Eye", "ear": "Ear", "shoulder": "Shoulder", "elbow": "Elbow", "wrist": "Wrist", "hip": "Hip", "knee": "Knee",
          "ankle": "Ankle", "heel": "Heel", "big_toe": "BigToe", "small_toe": "SmallToe", "foot_index": "BigToe"}
#: The same for joints with no side.
_CENTRAL = {"nose": "Nose", "neck": "Neck", "head": "Head", "hip": "MidHip"}
_SIDES = {"left": "L", "right": "R"}


def openpose_name(name: str) -> str:
    """OpenPose's name for a keypoint named the MediaPipe, COCO or Halpe way (``left_knee`` → ``LKnee``; MediaPipe's
    ``left_foot_index``, the tip of the foot, → ``LBigToe``; Halpe's ``hip``, mid-hips, → ``MidHip``) where OpenPose
    has the joint, else the name itself: masks, body parts and movement measures know a body by OpenPose's names."""
    if name in _CENTRAL:
        return _CENTRAL[name]
    side, _, part = name.partition("_")
    return _SIDES[side] + _SIDED[part] if side in _SIDES and part in _SIDED else name


def fixed_bones(names: tuple[str, ...] | list[str]) -> list[tuple[str, str]]:
    """The pairs among ``names`` whose distance no pose changes: the limbs' long bones, each ankle to its
    heel and toes, hip to hip, the neck to each shoulder (the collarbones), the neck to the head, and the
    head's points among themselves. The torso's diagonals, the neck to the nose and toe to toe are left out:
    the spine, the neck and the toes bend."""
    present = set(names)
    head = [name for name in HEAD if name in present]
    pairs = [*LIMB_BONES, *((foot[0], point) for foot in FEET for point in foot[1:]), ("LHip", "RHip"), ("Neck", "LShoulder"),
             ("Neck", "RShoulder"), ("Neck", "Head"), *((a, b) for i, a in enumerate(head) for b in head[i + 1:])]
    return [(a, b) for a, b in pairs if a in present and b in present]


def torso_length(point: Callable[[str], np.ndarray]) -> np.ndarray:
    """Mid-shoulders to mid-hips, ``point(name)`` giving each corner's position ([..., D] arrays, any
    leading shape): the body's size that widths and reaches are taken in proportion to."""
    shoulders = (point("LShoulder") + point("RShoulder")) / 2
    hips = (point("LHip") + point("RHip")) / 2
    return np.linalg.norm(shoulders - hips, axis=-1)
