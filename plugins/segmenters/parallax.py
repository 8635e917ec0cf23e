"""``parallax``: subject masks from nothing but the calibrated videos — what the cameras agree stands off
the floor.

A rig's cameras look down at a floor or mat. Warped from one camera into another through the floor
plane, the floor lands on itself, so the two images agree there; anything standing off the plane lands
elsewhere, so they disagree (plane plus parallax). Each step:

1. **The floor plane**, from the calibration and the images: its normal is the normal of the plane
   through the camera centres (the cameras of a rig stand at about one height), turned to the cameras'
   "up"; its height is the one, swept along the normal below the cameras, at which neighbouring cameras'
   median images agree best through the plane's warp.
2. **Off-plane pixels** of each camera and frame: the pixels whose colour disagrees with most of the
   other cameras' colour at the same floor point. A floor pixel one other camera cannot see (the subject
   hides it there) disagrees with that camera only, so a majority keeps it floor.
3. **What the cameras agree on in 3D**: voxels above the floor, inside the rig, kept where most cameras
   that see them find them off-plane; a camera's mask is its off-plane pixels near the projection of the
   kept voxels, holes filled. A bystander outside the rig and a floor pixel only one camera calls
   off-plane drop out.
4. **Where the subject can be** (``region = "change"``, :mod:`.change_region`): the convex hull, grown by
   ``margin``, of the voxels the cameras agree changed colour at some time over the sequence. Static
   equipment off the floor (a treadmill, a mat's fold) never changes and falls outside it; the still parts
   between the moving ones (an infant's trunk) fall inside. Within it, a camera's mask also takes the
   pixels that change at that frame, and those whose floor point no other camera sees (the floor cannot
   judge them: a standing subject's upper body, seen against the walls) that changed within
   ``change_window`` frames of it. Changed at any time would keep everywhere a moving subject went. A
   subject that never moves leaves no region: the masks are then not restricted.
5. **Refined against plates** (``refine = "plate"``, when the session has plates, e.g. estimated by
   ``mmcsplat plates`` with these masks held out): the geometric mask keeps only the pixels within
   ``refine_radius`` of one that differs from the plate. The plate trims the outline, where the
   geometric mask spills onto the floor beside the subject. Within the hull of change, the pixels whose
   floor point no other camera sees are left unrefined: the first masks are weakest there, so a plate
   estimated with them held out may show the still subject itself (a standing adult's torso facing the
   camera, seen against the walls), and refining against it would drop the subject. There the plate adds
   instead: a pixel that differs from it joins the mask (an arm held still for longer than the window,
   where the plate shows the wall behind it). And a pixel kept there for its change within the window
   stays only where it still differs from the plate by ``window_threshold``: the wall the subject has
   just left matches the plate.
6. **What recurs is the wall** (``recurrence``): a pixel of the hull whose floor point no other camera
   sees leaves the mask where its colour at the frame recurs, within ``recurrence_threshold`` grey
   levels, in at least ``recurrence`` of the frames sampled over the sequence, unless the cameras'
   geometry holds it (step 3). The wall beside a body shows its colour whenever the body is elsewhere;
   a body part over a pixel changes as it moves. This needs no plate, so it also clears the halo that a
   plate with a ghost of the subject leaves about the body (the plate differs from the wall there). The
   floor judges every other pixel: a subject on a mat seen from above keeps its still trunk. A limb held
   still against a wall for ``recurrence`` of the sequence leaves the mask where it rests.

Every piece of a mask is kept (``keep = "all"``) but the specks under ``min_piece`` of its largest: bounded in 3D
as the masks are, a body the plate test cuts at the belt is still the subject in both pieces.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import attrs
import cv2
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.parameters import at_least, between, finite_positive, one_of, parameter
from mmcsplat.plugins.segmenters.change_region import changed, hull_masks, main_pieces, moving_voxels
from mmcsplat.plugins.segmenters.postprocess import KEEP, PostProcessedSegmenter, dilate, open_close, present_frames
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.rig import rig_center
from mmcsplat.scene.visual_hull import image_hits, pixel_rays
from mmcsplat.storage.session import SessionReader

#: Floor heights tried by the sweep, spread over [SWEEP_RANGE] × the rig centre's depth below the cameras,
#: then as many again between the best one's neighbours.
SWEEP_STEPS = 25
SWEEP_RANGE = (0.5, 2.0)
#: Frames whose per-pixel median the sweep compares (a moving subject drops out of the median).
SWEEP_SAMPLES = 9
#: Width in pixels the sweep's images are reduced to (the floor is large: a coarse image finds it).
SWEEP_WIDTH = 64
#: Grey levels under which two warped pixels agree in the sweep.
SWEEP_AGREEMENT = 12.0
#: Frames, spread over the sequence, whose median and changes the subject's region comes from.
REGION_SAMPLES = 30


@attrs.frozen(eq=False)
class Plane:
    """The floor: the points x with ``normal`` · x = ``offset`` (``normal`` a unit vector towards the
    cameras)."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distance [N] of ``points`` [N, 3] above the plane."""
        return points @ self.normal - self.offset


def floor_normal(cameras: Sequence[Camera]) -> np.ndarray:
    """The unit normal of the plane through the camera centres (their mean "up" direction when they are
    fewer than 3 or in a line), turned to the side the cameras' image "up" points to."""
    up = -np.mean([camera.R[1] for camera in cameras], axis=0)  # image rows grow downwards
    centres = np.array([camera.center for camera in cameras])
    normal = up
    if len(cameras) >= 3:
        singular, vectors = np.linalg.svd(centres - centres.mean(axis=0))[1:]
        if singular[1] > 1e-3 * singular[0]:  # the centres span a plane
            normal = vectors[2]
    normal = normal / np.linalg.norm(normal)
    return normal if normal @ up >= 0 else -normal


def floor_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(centre [3], unit ray directions [H·W, 3]) of every pixel of ``camera``, row-major."""
    ys, xs = np.mgrid[0 : camera.height, 0 : camera.width]
    points = pixel_rays(camera, np.stack([xs.ravel(), ys.ravel()], axis=1), np.ones(1))[:, 0]
    directions = points - camera.center
    return camera.center, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def plane_warp(source: Camera, target: Camera, rays: tuple[np.ndarray, np.ndarray], plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """(map [H, W, 2] float32 for :func:`cv2.remap`, valid [H, W] bool): where the floor point seen by
    each pixel of ``source`` (its ``rays``) lies in ``target``'s image; invalid where the ray misses the
    floor or the point falls outside ``target``'s view."""
    centre, directions = rays
    along = directions @ plane.normal
    distance = (plane.offset - centre @ plane.normal) / np.where(np.abs(along) > 1e-9, along, np.nan)
    points = centre + np.nan_to_num(distance)[:, None] * directions
    pixels = target.project(points)
    depth = (points @ target.R.T + target.t)[:, 2]
    valid = (distance > 0) & (depth > 0) & np.all((pixels >= 0) & (pixels <= [target.width - 1, target.height - 1]), axis=1)
    shape = (source.height, source.width)
    return pixels.reshape(*shape, 2).astype(np.float32), valid.reshape(shape)


def colour_difference(image: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The largest per-channel absolute difference [H, W] float32 of two [H, W, 3] images."""
    return np.abs(image.astype(np.float32) - other.astype(np.float32)).max(axis=-1)


def range_difference(image: np.ndarray, warped: np.ndarray) -> np.ndarray:
    """How far [H, W] float32 (largest over channels) each pixel of ``image`` lies outside the range of
    colours ``warped`` holds in its 3 × 3 neighbourhood: a warp a pixel off (calibration, resampling) on a
    sharp edge of the floor's texture (tile joints) still agrees."""
    kernel = np.ones((3, 3), np.uint8)
    image = image.astype(np.int16)
    above = image - cv2.dilate(warped, kernel).astype(np.int16)
    below = cv2.erode(warped, kernel).astype(np.int16) - image
    return np.maximum(np.maximum(above, below), 0).max(axis=-1).astype(np.float32)


def sweep_floor(cameras: Sequence[Camera], medians: Sequence[np.ndarray], normal: np.ndarray) -> Plane:
    """The floor plane with ``normal``: the offset, swept over :data:`SWEEP_RANGE` × the rig centre's depth
    below the cameras (coarse, then fine), at which the cameras' ``medians`` (images [H, W, 3]) agree best
    with their two nearest neighbours' through the plane's warp (the share of overlapping pixels within
    :data:`SWEEP_AGREEMENT` grey levels)."""
    scale = min(1.0, SWEEP_WIDTH / max(camera.width for camera in cameras))
    small = [camera.scaled(scale) for camera in cameras]
    images = [cv2.resize(image, (camera.width, camera.height), interpolation=cv2.INTER_AREA) for camera, image in zip(small, medians, strict=True)]
    rays = [floor_rays(camera) for camera in small]
    centres = np.array([camera.center for camera in cameras])
    top = float(np.mean(centres @ normal))
    depth = top - float(rig_center(cameras) @ normal)  # the rig centre's depth below the cameras
    if depth <= 0:
        raise InputError("parallax segmenter: the cameras do not look down at a common point, so no floor lies below them to tell the "
                         "subject by: bring masks, 2D keypoints (run --keypoints) or clean plates with the capture, or choose another "
                         "segmenter (--segmenter; keypoints, or background with a recorded plate)")
    pairs = [(i, int(j)) for i in range(len(cameras)) for j in np.argsort(np.linalg.norm(centres - centres[i], axis=1))[1:3]]

    def agreement(offset: float) -> float:
        plane = Plane(normal, offset)
        agree = total = 0
        for i, j in pairs:
            warp, valid = plane_warp(small[i], small[j], rays[i], plane)
            warped = cv2.remap(images[j], warp, None, cv2.INTER_LINEAR)
            agree += int((colour_difference(images[i], warped)[valid] < SWEEP_AGREEMENT).sum())
            total += int(valid.sum())
        return agree / total if total else 0.0

    offsets = top - depth * np.linspace(*SWEEP_RANGE, SWEEP_STEPS)
    best = int(np.argmax([agreement(float(offset)) for offset in offsets]))
    offsets = np.linspace(offsets[max(best - 1, 0)], offsets[min(best + 1, SWEEP_STEPS - 1)], SWEEP_STEPS)
    return Plane(normal, float(offsets[int(np.argmax([agreement(float(offset)) for offset in offsets]))]))


def sampled_frames(session: SessionReader, camera: str, samples: int) -> np.ndarray:
    """[S, H, W, 3] uint8: up to ``samples`` frames spread over ``camera``'s sequence."""
    frames = present_frames(session, camera)
    picks = frames[np.unique(np.linspace(0, len(frames) - 1, min(samples, len(frames))).round().astype(int))]
    return np.stack([session.frame(int(t), camera).rgb for t in picks])


def recurrence_share(image: np.ndarray, samples: np.ndarray, threshold: float) -> np.ndarray:
    """[H, W] float: the share of ``samples`` [S, H, W, 3] whose colour at each pixel lies within ``threshold``
    grey levels (largest channel difference) of ``image``'s [H, W, 3]."""
    within = (int(np.ceil(threshold)) - 1,) * 3  # a difference under the threshold, in whole grey levels
    count = np.zeros(image.shape[:2], np.int32)
    for sample in samples:  # one image-sized difference at a time (the samples may be full-size frames), in OpenCV's
        count += cv2.inRange(cv2.absdiff(sample, image), (0, 0, 0), within) > 0  # single passes: 13× numpy's max over channels
    return count / len(samples)


def median_image(session: SessionReader, camera: str, samples: int) -> np.ndarray:
    """The per-pixel median [H, W, 3] uint8 of ``samples`` frames spread over ``camera``'s sequence."""
    return np.median(sampled_frames(session, camera, samples), axis=0).astype(np.uint8)


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """[3, 3] rows: two unit vectors along the plane with ``normal``, and the normal."""
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(normal, a), normal])


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every background region not connected to the image border filled."""
    padded = np.pad(mask.astype(np.uint8), 1)
    flood = padded.copy()
    cv2.floodFill(flood, None, (0, 0), 1)
    return (mask | (flood[1:-1, 1:-1] == 0)).astype(bool)


@attrs.frozen
class ParallaxSegmenter(PostProcessedSegmenter):
    """The subject is what the cameras agree stands off the floor (module docstring): plane plus parallax
    against the floor plane found from the calibration and the images, fused over voxels above the floor,
    optionally refined against the session's plates. Needs at least 3 cameras that look down at a floor."""

    threshold: float = parameter(15.0, doc="grey levels by which a camera's pixel must differ from another camera's colour at the same "
                                           "floor point to disagree", validator=finite_positive)
    majority: float = parameter(0.7, doc="share of the other cameras seeing a pixel's floor point that must disagree for it to be off-plane",
                                validator=between(0, 1))
    min_height: float = parameter(0.01, doc="metres above the floor where the voxels start (the floor's own unevenness)", validator=at_least(0))
    voxels: int = parameter(60, doc="voxels along the reach (their size: the reach over this)", validator=at_least(4))
    reach: float = parameter(0.5, doc="the voxels' horizontal reach from the rig centre, as a share of the cameras' horizontal "
                                      "distance from it (a bystander at the rig's edge stays out)", validator=finite_positive)
    agreement: float = parameter(0.8, doc="share of the cameras seeing a voxel that must find it off-plane for it to be the subject",
                                 validator=between(0, 1))
    passes: int = parameter(2, doc="passes: each after the first lets only the cameras whose last mask leaves a floor point "
                                   "uncovered judge it", validator=at_least(1))
    near: int = parameter(1, doc="pixels a camera's off-plane pixels may lie from its kept voxels' projection", validator=at_least(0))
    region: str = parameter("change", doc="change: keep the masks within the hull of what the cameras agree changed over the sequence "
                                          "(module docstring), or none", validator=one_of("change", "none"))
    change_threshold: float = parameter(20.0, doc="change: grey levels by which a pixel must differ from its sequence's median to have "
                                                  "changed", validator=finite_positive)
    margin: float = parameter(0.1, doc="change: metres the hull of the changed voxels is grown by", validator=at_least(0))
    change_window: int = parameter(5, doc="change: frames either side of a mask's within which a pixel of the hull whose floor point no "
                                          "other camera sees must have changed to be kept", validator=at_least(0))
    refine: str = parameter("none", doc="none, or plate: keep only the mask's pixels near one that differs from the session's plate",
                            validator=one_of("none", "plate"))
    refine_threshold: float = parameter(30.0, doc="plate: grey levels a pixel must differ from the plate by", validator=finite_positive)
    window_threshold: float = parameter(8.0, doc="plate: grey levels by which a pixel kept for its change within the window, where no other "
                                                "camera sees its floor point, must still differ from the plate", validator=at_least(0))
    refine_radius: int = parameter(0, doc="plate: pixels a kept pixel may lie from one that differs from the plate", validator=at_least(0))
    recurrence: float = parameter(0.3, doc="change: share of the sequence's sampled frames in which the colour of a pixel of the hull whose "
                                           "floor point no other camera sees must recur for the pixel to leave the mask as the wall (1 keeps them)",
                                  validator=between(0, 1))
    recurrence_threshold: float = parameter(10.0, doc="change: grey levels within which a colour recurs", validator=finite_positive)
    close_radius: int = parameter(2, doc="morphological closing of the mask, pixels (0 skips)", validator=at_least(0))
    # Every large piece is the subject: the voxels bound the masks to the rig and the hull of change to what moved,
    # while a body splits in an image where dark clothes pass before a dark floor (the Pose2Sim demo's cam_01 and
    # cam_02 kept only the legs as the central piece).
    keep: str = parameter("all", doc="the mask's component kept: all (the voxels and the hull of change bound the mask), central or "
                                     "largest", validator=one_of(*KEEP))
    min_piece: float = parameter(0.05, doc="all: a piece under this share of the mask's largest goes (the specks along the floor's edges "
                                           "that the plate test leaves)", validator=between(0, 1))
    _cache: dict = attrs.field(factory=dict, init=False, repr=False, eq=False)

    def raw(self, session: SessionReader, camera: str) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        plate = self._plate(session, camera) if self.refine == "plate" else None
        region = self.subject_region(session).get(camera) if self.region == "change" else None
        median, hull, unjudged = region if region is not None else (None, None, None)
        samples = sampled_frames(session, camera, REGION_SAMPLES) if region is not None and self.recurrence < 1 else None
        for t, image, now, near in self._changes(session, camera, median):
            geometric = mask = self._masks(session, t)[camera]
            if region is not None:
                mask, recent = hull & (mask | now), unjudged & near
            if plate is not None:
                difference = colour_difference(image, plate)
                differs = difference > self.refine_threshold
                if region is not None:
                    # A plate there may show the still subject itself, so it never cuts; it adds a limb held still for longer
                    # than the window, and takes from the window's change the wall the subject has just left.
                    recent = (recent & (difference > self.window_threshold)) | (unjudged & differs)
                    differs |= unjudged
                mask = mask & dilate(differs, self.refine_radius)
            if region is not None:
                mask |= recent
                if samples is not None:  # what the cameras' geometry holds stays
                    mask &= ~(unjudged & ~geometric & (recurrence_share(image, samples, self.recurrence_threshold) >= self.recurrence))
            yield t, fill_holes(open_close(mask, 0, self.close_radius)), None

    def _changes(self, session: SessionReader, camera: str, median: np.ndarray | None
                 ) -> Iterator[tuple[int, np.ndarray, np.ndarray | None, np.ndarray | None]]:
        """(t, image, changed, changed near) for each present frame of ``camera``: the [H, W] bool pixels that
        differ from ``median`` at t, and at any of the present frames up to ``change_window`` either side
        (None without a median). Each frame is read once, and only the window's are held."""
        frames = [int(t) for t in present_frames(session, camera)]
        window = self.change_window if median is not None else 0
        held: dict[int, tuple[np.ndarray, np.ndarray | None]] = {}
        for i, t in enumerate(frames):
            near = frames[max(i - window, 0) : i + window + 1]
            for s in near:
                if s not in held:
                    image = session.frame(s, camera).rgb
                    held[s] = (image, None if median is None else changed(image, median, self.change_threshold))
            held = {s: held[s] for s in near}
            image, now = held[t]
            yield t, image, now, None if median is None else np.any([held[s][1] for s in near], axis=0)

    def _plate(self, session: SessionReader, camera: str) -> np.ndarray:
        plate = session.plate(camera)
        if plate is None:
            raise InputError(f"{session.url}: camera {camera!r} has no plate for the parallax segmenter's refine = plate: estimate "
                             f"plates with `mmcsplat plates {session.url}` after a first segmentation, or set refine = none")
        return plate

    def floor(self, session: SessionReader) -> Plane:
        """The session's floor plane (computed once per session)."""
        key = ("floor", str(session.url))
        if key not in self._cache:
            cameras = [session.camera(name) for name in session.camera_names]
            if len(cameras) < 3:
                raise InputError(f"{session.url}: the parallax segmenter needs at least 3 cameras, got {len(cameras)}; give the masks "
                                 "another way: from 2D keypoints (the keypoints segmenter; mmcsplat run --keypoints PATH), clean plates "
                                 "(background), or a person-segmentation plugin (--segmenter NAME)")
            medians = [median_image(session, name, SWEEP_SAMPLES) for name in session.camera_names]
            self._cache[key] = sweep_floor(cameras, medians, floor_normal(cameras))
        return self._cache[key]

    def subject_region(self, session: SessionReader) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per camera (none when nothing changed): (its sequence's median image, the projection of the hull of
        change, the pixels of that projection whose floor point no other camera sees) — :mod:`.change_region`."""
        key = ("region", str(session.url))
        if key not in self._cache:
            names = list(session.camera_names)
            cameras = [session.camera(name) for name in names]
            plane = self.floor(session)
            medians, ever = [], []
            for name in names:
                frames = sampled_frames(session, name, REGION_SAMPLES)
                median = np.median(frames, axis=0).astype(np.uint8)
                medians.append(median)
                ever.append(np.any([changed(frame, median, self.change_threshold) for frame in frames], axis=0))
            top = float(np.mean(plane.height(np.array([camera.center for camera in cameras]))))
            grid, size = self._grid(cameras, plane, top)
            moving = grid[moving_voxels(grid, cameras, [dilate(mask, self.near) for mask in ever], self.agreement)]
            region = {}
            if len(moving):
                moving = moving[main_pieces(moving, plane_basis(plane.normal), size)]
                for camera, median, hull in zip(cameras, medians, hull_masks(moving, cameras, self.margin), strict=True):
                    judged = np.any([self._warp(session, camera, other)[1] for other in cameras if other.name != camera.name], axis=0)
                    region[camera.name] = (median, hull, hull & ~judged)
            self._cache[key] = region
        return self._cache[key]

    def _warp(self, session: SessionReader, camera: Camera, other: Camera) -> tuple[np.ndarray, np.ndarray]:
        """:func:`plane_warp` of ``camera``'s pixels into ``other`` through the session's floor (computed once)."""
        key = ("warp", str(session.url), camera.name, other.name)
        if key not in self._cache:
            rays_key = ("rays", str(session.url), camera.name)
            if rays_key not in self._cache:
                self._cache[rays_key] = floor_rays(camera)
            self._cache[key] = plane_warp(camera, other, self._cache[rays_key], self.floor(session))
        return self._cache[key]

    def _masks(self, session: SessionReader, t: int) -> dict[str, np.ndarray]:
        """Every camera's geometric mask at frame ``t``. Each needs every camera's image of the frame and
        the session's cameras are segmented one after another, so a frame's masks are kept once made (bit
        packed: an eighth of a byte per pixel and camera)."""
        key = ("frame", str(session.url), t)
        if key not in self._cache:
            names = [name for name in session.camera_names if session.present(name)[t]]
            cameras = [session.camera(name) for name in names]
            images = [session.frame(t, name).rgb for name in names]
            masks = self._fused(session, cameras, self._off_plane(session, cameras, images))
            for _ in range(self.passes - 1):
                masks = self._fused(session, cameras, self._off_plane(session, cameras, images, masks))
            self._cache[key] = {name: (np.packbits(mask), mask.shape) for name, mask in zip(names, masks, strict=True)}
        return {name: np.unpackbits(bits, count=int(np.prod(shape))).reshape(shape).astype(bool) for name, (bits, shape) in self._cache[key].items()}

    def _fused(self, session: SessionReader, cameras: Sequence[Camera], off: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Each camera's ``off``-plane pixels near the projection of the voxels most cameras agree on."""
        kept = self._voxels(session, cameras, off)
        masks = []
        for camera, off_plane in zip(cameras, off, strict=True):
            footprint = np.zeros((camera.height, camera.width), np.uint8)
            pixels = np.round(camera.project(kept)).astype(int) if len(kept) else np.zeros((0, 2), int)
            inside = np.all((pixels >= 0) & (pixels < [camera.width, camera.height]), axis=1)
            footprint[pixels[inside, 1], pixels[inside, 0]] = 1
            masks.append(off_plane & dilate(open_close(footprint.astype(bool), 0, 2), self.near))
        return masks

    def _off_plane(self, session: SessionReader, cameras: Sequence[Camera], images: Sequence[np.ndarray],
                   masks: Sequence[np.ndarray] | None = None) -> list[np.ndarray]:
        """Per camera, [H, W] bool: the pixels most other cameras disagree with at their floor point. With
        the cameras' ``masks`` of an earlier pass, a camera whose mask covers the floor point (the subject
        hides it there) has no say, and a pixel no camera sees the floor point of keeps its mask."""
        off = []
        for i, camera in enumerate(cameras):
            votes = np.zeros((camera.height, camera.width), np.int32)
            seen = np.zeros_like(votes)
            for j, other in enumerate(cameras):
                if j == i:
                    continue
                warp, valid = self._warp(session, camera, other)
                if masks is not None:
                    hidden = cv2.remap(dilate(masks[j], self.near).astype(np.uint8), warp, None, cv2.INTER_NEAREST)
                    valid = valid & (hidden == 0)
                warped = cv2.remap(images[j], warp, None, cv2.INTER_LINEAR)
                seen += valid
                votes += valid & (range_difference(images[i], warped) > self.threshold)
            decided = (seen > 0) & (votes > self.majority * seen)
            off.append(decided if masks is None else decided | ((seen == 0) & masks[i]))
        return off

    def _voxels(self, session: SessionReader, cameras: Sequence[Camera], off: Sequence[np.ndarray]) -> np.ndarray:
        """Centres [N, 3] of the voxels above the floor, within the rig, that most cameras seeing them find off-plane."""
        grid = self._grid_views(session)
        seen, inside = np.zeros(len(grid[0]), int), np.zeros(len(grid[0]), int)
        for camera, off_plane in zip(cameras, off, strict=True):
            sees, pixel = grid[1][camera.name]
            seen += sees
            inside += sees & off_plane.ravel()[pixel]
        return grid[0][(seen >= 2) & (inside >= self.agreement * seen)]

    def _grid_views(self, session: SessionReader) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
        """(the voxel centres [N, 3] :meth:`_voxels` judges, per camera name (seen [N] bool, flat pixel index
        [N] int)), computed once: projecting the grid anew at every frame and pass was most of a frame's time."""
        key = ("grid", str(session.url))
        if key not in self._cache:
            plane = self.floor(session)
            cameras = [session.camera(name) for name in session.camera_names]
            grid = self._grid(cameras, plane, 2 * float(plane.height(rig_center(cameras)[None])[0]))[0]
            views = {}
            for camera in cameras:
                pixels, sees = image_hits(grid, camera)
                views[camera.name] = (sees, np.where(sees, pixels[:, 1] * camera.width + pixels[:, 0], 0))
            self._cache[key] = (grid, views)
        return self._cache[key]

    def _grid(self, cameras: Sequence[Camera], plane: Plane, top: float) -> tuple[np.ndarray, float]:
        """(voxel centres [N, 3], their size) over the floor ``plane``: within ``reach`` of the rig centre's
        foot, from ``min_height`` up to ``top`` metres above the floor (at least half the reach)."""
        normal = plane.normal
        centre = rig_center(cameras)
        foot = centre - plane.height(centre[None])[0] * normal
        horizontal = [camera.center - foot - plane.height(camera.center[None])[0] * normal for camera in cameras]
        reach = self.reach * float(np.mean(np.linalg.norm(horizontal, axis=1)))
        top = max(top, reach / 2)
        a, b, _ = plane_basis(normal)
        size = reach / self.voxels
        across = np.arange(-reach, reach + 1e-9, size)
        up = np.arange(self.min_height + size / 2, top, size)
        u, v, h = np.meshgrid(across, across, up, indexing="ij")
        keep = np.hypot(u, v).ravel() <= reach
        points = foot + u.ravel()[:, None] * a + v.ravel()[:, None] * b + h.ravel()[:, None] * normal
        return points[keep], size
