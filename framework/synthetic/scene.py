"""The synthetic scene rendered for one camera: a static layer (the mat, the floor around it and an
optional adult's leg), ray-cast once per camera, and the moving infant ray-cast each frame and composited
over it by depth. Lambertian shading under a fixed light plus ambient, no shadows, so every surface looks
the same from every camera (as the Gaussians, with no view-dependent colour, model it)."""

from __future__ import annotations

import attrs
import numpy as np

from mmcsplat.scene.camera import Camera
from mmcsplat.synthetic.body import BodyPose, Part
from mmcsplat.synthetic.cameras import RING_RADIUS, pixel_rays, sphere_pixel_boxes
from mmcsplat.synthetic.raycast import intersect_capsule, intersect_ellipsoid, intersect_ground
from mmcsplat.synthetic.textures import albedo

LIGHT = np.array([0.35, -0.25, 1.0]) / np.linalg.norm([0.35, -0.25, 1.0])  # towards the light
AMBIENT, DIFFUSE = 0.35, 0.65
VOID_COLOUR = np.array([0.8, 0.82, 0.85])  # beyond the floor: no surface, depth 0
GROUND_HALF_SIZE = 3.0  # metres: the floor is a 6 m square

# What a ray of the static layer hits.
VOID, GROUND, ADULT = 0, 1, 2


@attrs.frozen(eq=False)
class AdultLeg:
    """A capsule standing on the floor (an adult beside the mat): the segment ``bottom``–``top`` and its
    ``radius``, metres."""

    bottom: np.ndarray
    top: np.ndarray
    radius: float

    @classmethod
    def beside_mat(cls, azimuth: float) -> AdultLeg:
        """A leg just inside the camera ring at ``azimuth`` (radians), up to hip height."""
        radius = 0.07
        foot = 0.8 * RING_RADIUS * np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        return cls(foot + [0, 0, radius], foot + [0, 0, 0.9], radius)

    def describe(self) -> dict:
        """JSON-ready parameters."""
        return {"bottom": self.bottom.tolist(), "top": self.top.tolist(), "radius": self.radius}


@attrs.frozen(eq=False)
class StaticHits:
    """Per ray of one camera, what the static scene shows: ``depth`` [N] (camera z; ``inf`` where nothing
    is hit) and ``label`` [N] (VOID, GROUND or ADULT), which picks the texture."""

    depth: np.ndarray
    label: np.ndarray


def shade(colour: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Lambertian shading of albedo ``colour`` [N, 3] with unit ``normals`` [N, 3]."""
    return colour * (AMBIENT + DIFFUSE * np.clip(normals @ LIGHT, 0.0, None))[:, None]


def cast_static(origin: np.ndarray, directions: np.ndarray, leg: AdultLeg | None) -> StaticHits:
    """The floor, the mat and the adult's leg along each ray."""
    depth = intersect_ground(origin, directions, GROUND_HALF_SIZE)
    label = np.where(np.isfinite(depth), GROUND, VOID).astype(np.int8)
    if leg is not None:
        s = intersect_capsule(origin, directions, leg.bottom, leg.top, leg.radius)
        label[s < depth] = ADULT
        depth = np.minimum(depth, s)
    return StaticHits(depth, label)


def paint_static(origin: np.ndarray, directions: np.ndarray, hits: StaticHits, leg: AdultLeg | None) -> np.ndarray:
    """The shaded colour [N, 3] along each ray."""
    colour = np.tile(VOID_COLOUR, (len(directions), 1))
    points = origin + np.where(np.isfinite(hits.depth), hits.depth, 0.0)[:, None] * directions
    ground = hits.label == GROUND
    points[ground, 2] = 0.0  # exactly on the plane: rounding must not pick a texture cell below it
    colour[ground] = shade(albedo("mat", points[ground]), np.tile([0.0, 0.0, 1.0], (int(ground.sum()), 1)))
    if leg is not None:
        adult = hits.label == ADULT
        axis = leg.top - leg.bottom
        along = np.clip((points[adult] - leg.bottom) @ axis / (axis @ axis), 0.0, 1.0)
        normals = (points[adult] - leg.bottom - along[:, None] * axis) / leg.radius
        colour[adult] = shade(albedo("jeans", points[adult]), normals)
    return colour


@attrs.frozen(eq=False)
class BodyHits:
    """Where the infant is in front of the static layer: ``depth`` [N] of every ray (the nearer of body and
    static layer), and for the ``rays`` [M] that see the body, the ``part`` [M] seen and the hit ``unit``
    [M, 3] in that part's unit-sphere frame (see :func:`~.raycast.intersect_ellipsoid`)."""

    depth: np.ndarray
    rays: np.ndarray
    part: np.ndarray
    unit: np.ndarray


def cast_body(
    origin: np.ndarray, directions: np.ndarray, grid: np.ndarray, boxes: np.ndarray, parts: tuple[Part, ...], pose: BodyPose, under: np.ndarray
) -> BodyHits:
    """Ray-cast the infant in ``pose`` (one frame: rotations [P, 3, 3], origins [P, 3]) in front of depths
    ``under`` [N]. ``grid`` [H, W, k] holds the indices into ``directions`` of each pixel's rays and
    ``boxes`` [P, 4] the pixel ranges (u0, u1, v0, v1) each part can cover: a part is intersected only with
    the rays of its box, z-buffer style."""
    centres = pose.to_world(np.arange(len(parts)), np.array([part.centre for part in parts]))
    depth = under.copy()
    owner = np.full(len(directions), -1)
    unit = np.empty((len(directions), 3))
    for i, (u0, u1, v0, v1) in enumerate(boxes):
        rays = grid[v0:v1, u0:u1].ravel()
        s, hit = intersect_ellipsoid(origin, directions[rays], pose.rotations[i], centres[i], parts[i].radii)
        nearer = s < depth[rays]
        rays = rays[nearer]
        depth[rays], owner[rays], unit[rays] = s[nearer], i, hit[nearer]
    rays = np.flatnonzero(owner >= 0)
    return BodyHits(depth, rays, owner[rays], unit[rays])


def paint_body(hits: BodyHits, parts: tuple[Part, ...], pose: BodyPose) -> np.ndarray:
    """The shaded colour [M, 3] of each ray that sees the body."""
    radii = np.array([part.radii for part in parts])[hits.part]
    local = np.array([part.centre for part in parts])[hits.part] + hits.unit * radii
    normals = np.einsum("nij,nj->ni", pose.rotations[hits.part], hits.unit / radii)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    colour = np.empty((len(hits.rays), 3))
    for material in {p.material for p in parts}:
        mine = np.isin(hits.part, [i for i, p in enumerate(parts) if p.material == material])
        colour[mine] = albedo(material, local[mine])
    return shade(colour, normals)


@attrs.frozen(eq=False)
class Image:
    """One rendered view: ``rgb`` [H, W, 3] uint8, the infant's ``mask`` [H, W] uint8 (1 inside) and
    ``depth`` [H, W] float32 camera z in metres (0 where no surface)."""

    rgb: np.ndarray
    mask: np.ndarray
    depth: np.ndarray


class ViewRenderer:
    """Renders one camera's view of the scene frame by frame. Colour averages ``samples``² rays per pixel
    (anti-aliasing, as a sensor integrates over its pixel); mask and depth come from the ray through the
    pixel centre, so they are exact at the pixel (u, v)."""

    def __init__(self, camera: Camera, samples: int, leg: AdultLeg | None) -> None:
        self.camera = camera
        self.samples = samples
        self.origin = camera.center
        h, w = camera.height, camera.width
        self.centre_rays = pixel_rays(camera, 1)
        self.centre_grid = np.arange(h * w).reshape(h, w, 1)
        self.centre_static = cast_static(self.origin, self.centre_rays, leg)
        self.sample_rays = pixel_rays(camera, samples)
        self.sample_grid = np.arange(h * w * samples**2).reshape(h, w, samples**2)
        self.sample_static = cast_static(self.origin, self.sample_rays, leg)
        k = samples**2
        self.sample_colour = paint_static(self.origin, self.sample_rays, self.sample_static, leg).reshape(h * w, k, 3)
        self.static_colour = self.sample_colour.mean(axis=1)  # [H·W, 3]: each pixel's average

    def plate(self) -> np.ndarray:
        """[H, W, 3] uint8: the empty scene — the mat without the infant or the adult, as a clean plate
        recorded before the session would show it — anti-aliased like the frames."""
        empty = cast_static(self.origin, self.sample_rays, None)
        colour = paint_static(self.origin, self.sample_rays, empty, None).reshape(self.camera.height, self.camera.width, -1, 3).mean(axis=2)
        return np.round(np.clip(colour, 0.0, 1.0) * 255).astype(np.uint8)

    def render(self, parts: tuple[Part, ...], pose: BodyPose) -> Image:
        """The view of the infant in ``pose`` (one frame)."""
        h, w = self.camera.height, self.camera.width
        centres = pose.to_world(np.arange(len(parts)), np.array([part.centre for part in parts]))
        boxes = sphere_pixel_boxes(self.camera, centres, np.array([part.radii.max() for part in parts]))
        centre = cast_body(self.origin, self.centre_rays, self.centre_grid, boxes, parts, pose, self.centre_static.depth)
        sampled = cast_body(self.origin, self.sample_rays, self.sample_grid, boxes, parts, pose, self.sample_static.depth)
        # Only pixels with a sample on the body change from the static average.
        k = self.samples**2
        pixels, slot = np.unique(sampled.rays // k, return_inverse=True)
        block = self.sample_colour[pixels]
        block[slot, sampled.rays % k] = paint_body(sampled, parts, pose)
        colour = self.static_colour.copy()
        colour[pixels] = block.mean(axis=1)
        colour = colour.reshape(h, w, 3)
        rgb = np.round(np.clip(colour, 0.0, 1.0) * 255).astype(np.uint8)
        depth = np.where(np.isfinite(centre.depth), centre.depth, 0.0).reshape(h, w).astype(np.float32)
        mask = np.zeros(h * w, dtype=np.uint8)
        mask[centre.rays] = 1
        return Image(rgb, mask.reshape(h, w), depth)
