"""The synthetic infant: a kinematic chain of ellipsoid body parts, its forward kinematics and its
labelled surface points.

World frame: metres, z up, the mat at z = 0. At rest the infant lies supine (face up) along the x axis,
head towards +x, its right side towards +y, centred near the origin. Each part has its own frame whose
origin is the joint attaching it to its parent; its ellipsoid is axis-aligned in that frame, so textures
and surface points defined in part coordinates move rigidly with the part.
"""

from __future__ import annotations

import attrs
import numpy as np


@attrs.frozen(eq=False)
class Part:
    """One rigid body part.

    ``parent`` indexes the parent part (-1 for the root); ``joint`` names the joint at this part's origin;
    ``offset`` is that joint in the parent's frame; ``rest`` the 3×3 rotation of this part's frame relative
    to the parent's at rest; ``centre`` and ``radii`` the ellipsoid in this part's frame; ``material`` the
    texture painted on it (:mod:`.textures`).
    """

    name: str
    parent: int
    joint: str
    offset: np.ndarray
    rest: np.ndarray
    centre: np.ndarray
    radii: np.ndarray
    material: str


@attrs.frozen(eq=False)
class BodyPose:
    """Part frames in world coordinates: ``rotations`` [..., P, 3, 3] (part → world) and ``origins``
    [..., P, 3] (the joint at each part's origin; the root's is the torso centre)."""

    rotations: np.ndarray
    origins: np.ndarray

    def to_world(self, part: np.ndarray, local: np.ndarray) -> np.ndarray:
        """World positions [..., N, 3] of points ``local`` [N, 3] given in the frames of parts ``part`` [N]."""
        return np.einsum("...nij,nj->...ni", self.rotations[..., part, :, :], local) + self.origins[..., part, :]


def _frame(x_axis: np.ndarray, up_hint: np.ndarray) -> np.ndarray:
    """A rotation whose columns are (x, y, z): x along ``x_axis``, z as close to ``up_hint`` as possible."""
    x = x_axis / np.linalg.norm(x_axis)
    z = up_hint - (up_hint @ x) * x
    z /= np.linalg.norm(z)
    return np.stack([x, np.cross(z, x), z], axis=1)


def infant_parts() -> tuple[Part, ...]:
    """The infant body (about 3 months old, 0.58 m crown to heel with the legs stretched).

    Authored as a rest pose in world coordinates — joint positions and limb directions of a supine infant
    with flexed, abducted legs and bent arms — then expressed relative to each parent.
    """
    up = np.array([0.0, 0.0, 1.0])
    # name, parent name, joint, joint position at rest (world), frame x axis (world), length, radii, material
    rows: list[tuple[str, str | None, str, np.ndarray, np.ndarray, float, tuple[float, float, float], str]] = [
        ("torso", None, "root", np.array([0.0, 0.0, 0.062]), np.array([1.0, 0, 0]), 0.0, (0.105, 0.072, 0.058), "onesie"),
        ("pelvis", "torso", "waist", np.array([-0.07, 0, 0.062]), np.array([1.0, 0, 0]), -0.09, (0.06, 0.07, 0.052), "diaper"),
        ("head", "torso", "neck", np.array([0.10, 0, 0.066]), np.array([1.0, 0, 0]), 0.144, (0.075, 0.062, 0.062), "head"),
    ]
    for side, s in (("left", -1.0), ("right", 1.0)):
        shoulder = np.array([0.07, s * 0.072, 0.074])
        upper_arm = np.array([-0.15, s * 0.85, -0.35])
        elbow = shoulder + 0.085 * upper_arm / np.linalg.norm(upper_arm)
        forearm = np.array([0.55, s * 0.45, 0.35])
        wrist = elbow + 0.075 * forearm / np.linalg.norm(forearm)
        hip = np.array([-0.10, s * 0.045, 0.052])
        thigh = np.array([-0.45, s * 0.35, 0.65])
        knee = hip + 0.105 * thigh / np.linalg.norm(thigh)
        shank = np.array([-0.5, s * 0.1, -0.6])
        ankle = knee + 0.10 * shank / np.linalg.norm(shank)
        rows += [
            (f"upper_arm_{side}", "torso", f"shoulder_{side}", shoulder, upper_arm, 0.085, (0.05, 0.025, 0.025), "onesie"),
            (f"lower_arm_{side}", f"upper_arm_{side}", f"elbow_{side}", elbow, forearm, 0.075, (0.044, 0.021, 0.021), "skin"),
            (f"hand_{side}", f"lower_arm_{side}", f"wrist_{side}", wrist, np.array([0.6, s * 0.3, 0.2]), 0.05, (0.032, 0.023, 0.012), "skin"),
            (f"thigh_{side}", "pelvis", f"hip_{side}", hip, thigh, 0.105, (0.062, 0.035, 0.035), "leggings"),
            (f"shank_{side}", f"thigh_{side}", f"knee_{side}", knee, shank, 0.10, (0.056, 0.028, 0.028), "leggings"),
            (f"foot_{side}", f"shank_{side}", f"ankle_{side}", ankle, np.array([-0.6, s * 0.1, 0.5]), 0.05, (0.04, 0.024, 0.016), "sock"),
        ]
    index = {row[0]: i for i, row in enumerate(rows)}
    world_frames = [_frame(row[4], up) for row in rows]
    parts = []
    for name, parent_name, joint, position, _, length, radii, material in rows:
        i = index[name]
        if parent_name is None:
            parent, offset, rest = -1, position, world_frames[i]
        else:
            parent = index[parent_name]
            parent_frame = world_frames[parent]
            offset = parent_frame.T @ (position - rows[parent][3])
            rest = parent_frame.T @ world_frames[i]
        # A limb's ellipsoid spans its segment (centre half-way along x); torso, pelvis and head are offset
        # by a signed length so they reach towards the neck, the legs or the crown.
        parts.append(Part(name, parent, joint, offset, rest, np.array([length / 2, 0.0, 0.0]), np.array(radii), material))
    return tuple(parts)


def rotation_matrices(rotvecs: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, vectorised: rotation vectors [..., 3] to matrices [..., 3, 3]."""
    theta = np.linalg.norm(rotvecs, axis=-1)[..., None, None]
    k = rotvecs / np.maximum(theta[..., 0], 1e-12)
    cross = np.zeros(rotvecs.shape[:-1] + (3, 3))
    cross[..., 0, 1], cross[..., 0, 2], cross[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    cross = cross - np.swapaxes(cross, -1, -2)
    return np.eye(3) + np.sin(theta) * cross + (1 - np.cos(theta)) * cross @ cross


def forward_kinematics(parts: tuple[Part, ...], joint_rotvecs: np.ndarray) -> BodyPose:
    """Part frames for joint rotations ``joint_rotvecs`` [..., P, 3] (each in its part's rest frame; the
    root's turns the whole body about the torso centre). Parents precede children in ``parts``."""
    local = rotation_matrices(joint_rotvecs)
    rotations = np.empty_like(local)
    origins = np.empty(joint_rotvecs.shape)
    for i, part in enumerate(parts):
        if part.parent < 0:
            rotations[..., i, :, :] = part.rest @ local[..., i, :, :]
            origins[..., i, :] = part.offset
        else:
            parent_rotation = rotations[..., part.parent, :, :]
            rotations[..., i, :, :] = parent_rotation @ part.rest @ local[..., i, :, :]
            origins[..., i, :] = origins[..., part.parent, :] + parent_rotation @ part.offset
    return BodyPose(rotations, origins)


def _fibonacci_sphere(count: int) -> np.ndarray:
    """``count`` nearly uniform unit vectors."""
    i = np.arange(count) + 0.5
    z = 1 - 2 * i / count
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def surface_points(parts: tuple[Part, ...], density: float = 2000.0) -> tuple[np.ndarray, np.ndarray]:
    """Labelled points on the outer body surface: (local positions [S, 3] in their part's frame, part index
    [S]). About ``density`` points per m² of each ellipsoid, dropping those buried inside another part at
    rest (where parts overlap at joints), so every point lies on the visible skin of the body."""
    rest = forward_kinematics(parts, np.zeros((len(parts), 3)))
    locals_, owners = [], []
    for i, part in enumerate(parts):
        a, b, c = part.radii
        area = 4 * np.pi * ((a**1.6 * b**1.6 + a**1.6 * c**1.6 + b**1.6 * c**1.6) / 3) ** (1 / 1.6)  # Thomsen
        points = part.centre + _fibonacci_sphere(max(8, round(area * density))) * part.radii
        world = rest.to_world(np.full(len(points), i), points)
        buried = np.zeros(len(points), dtype=bool)
        for j, other in enumerate(parts):
            if j != i:
                inside = rest.rotations[j].T @ (world - rest.origins[j]).T
                buried |= np.sum(((inside.T - other.centre) / (other.radii * 0.97)) ** 2, axis=1) < 1
        locals_.append(points[~buried])
        owners.append(np.full(int((~buried).sum()), i))
    return np.concatenate(locals_), np.concatenate(owners)
