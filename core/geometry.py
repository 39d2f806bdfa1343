"""How far a view stands from a place, in metres, from the two images: the geometric check.

Appearance says *which* place a view resembles, not how far from it the camera stood: a view half a
metre off the first lap's line looks as much like the place as one on it, and the matrix's off-pose
families (jitter, wander, the paper's noise model) name places 0.5–1 m away (docs/estimator.md,
"What limits off-pose revisits"). The map holds what scales it: the link from the place to a
neighbour, a measured odometry step. ORB features matched between the place's image and the
neighbour's are triangulated along that link, in metres; the view's features matched to those
points give its pose by PnP with RANSAC; the distance of that pose from the place is the answer.

OpenCV does each step (``ORB``, ``BFMatcher``, ``triangulatePoints``, ``solvePnPRansac``; its
RANSAC draws from a fixed seed, so the same inputs give the same answer).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

ORB_FEATURES = 500
"""Features per image. 500 on 4 levels removed as many wrong claims in the matrix's off-pose
families as 1,500 on 6 levels, at half the cost (3.4 against 7 ms an image at 320 × 240, one thread)."""
ORB_LEVELS = 4
MATCH_RATIO = 0.8
"""Lowe's ratio test: a match counts when its distance is under this × the second best's."""
MIN_MATCHES = 12
"""Matches between a place and its neighbour below which nothing is triangulated."""
MIN_INLIERS = 8
"""PnP inliers below which the view's pose is unknown (the check then says nothing)."""
REPROJECTION_PX = 2.0
"""A triangulated point must reproject within this in both images; PnP's inlier threshold too."""
DEPTH_M = (0.3, 30.0)
"""Triangulated points nearer or farther than these (in front of the place's camera) are dropped."""
MIN_BASELINE_M = 0.3
"""A neighbour nearer than this to the place (a turn in place) triangulates nothing reliable."""
TRIANGULATED_CACHE = 512
"""Place–neighbour pairs whose points are kept (each a few kilobytes): revisits ask the same pairs."""

# Robot frame (x forward, y left, z up) to camera frame (x right, y down, z forward).
_ROBOT_TO_CAMERA = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class PinholeCamera:
    """The focal length and principal point, in pixels, of images of ``width_px`` × ``height_px``."""

    fx: float
    cx: float
    cy: float
    width_px: int
    height_px: int

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fx, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class ViewFeatures:
    """ORB keypoints of one image: ``points`` (n, 2) float32 pixels, ``descriptors`` (n, 32) uint8."""

    points: np.ndarray
    descriptors: np.ndarray


def view_features(gray: np.ndarray) -> ViewFeatures:
    """ORB features of a grey image (a detector of its own per call: the reader's threads share none)."""
    import cv2

    orb = cv2.ORB.create(
        nfeatures=ORB_FEATURES, scaleFactor=1.2, nlevels=ORB_LEVELS, edgeThreshold=15, fastThreshold=7
    )
    keypoints, descriptors = orb.detectAndCompute(gray, None)
    if descriptors is None:
        return ViewFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8))
    return ViewFeatures(np.array([k.pt for k in keypoints], dtype=np.float32).reshape(-1, 2), descriptors)


def _matches(a: ViewFeatures, b: ViewFeatures) -> tuple[np.ndarray, np.ndarray]:
    """Indices into ``a`` and ``b`` of the matches that pass the ratio test."""
    import cv2

    if len(a.descriptors) < 2 or len(b.descriptors) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(a.descriptors, b.descriptors, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < MATCH_RATIO * p[1].distance]
    return np.array([m.queryIdx for m in good], np.int64), np.array([m.trainIdx for m in good], np.int64)


def _camera_motion(rel: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` with X_a = R X_b + t in camera coordinates, for planar pose ``rel`` of b seen from a."""
    x, y, yaw = rel
    c, s = math.cos(yaw), math.sin(yaw)
    planar = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return _ROBOT_TO_CAMERA @ planar @ _ROBOT_TO_CAMERA.T, _ROBOT_TO_CAMERA @ np.array([x, y, 0.0])


class GeometricCheck:
    """Metric offsets of views from places, with the triangulated points of recent place pairs kept."""

    def __init__(self, camera: PinholeCamera) -> None:
        self._k = camera.matrix
        self._triangulated: OrderedDict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def offset_m(
        self,
        place_id: int,
        place: ViewFeatures,
        neighbours: list[tuple[int, ViewFeatures, tuple[float, float, float]]],
        view: ViewFeatures,
    ) -> float | None:
        """How far from the place the view's camera stood (metres), or None when the images cannot
        say (too few matches, no neighbour a baseline away). ``neighbours``: (id, features, pose seen
        from the place) of places linked to it; the one giving the most PnP inliers answers."""
        import cv2

        best: tuple[int, float] | None = None
        matched: tuple[np.ndarray, np.ndarray] | None = None  # place to view, whichever neighbour
        for neighbour_id, neighbour, rel in neighbours:
            if math.hypot(rel[0], rel[1]) < MIN_BASELINE_M:
                continue
            indices, points = self._points(place_id, place, neighbour_id, neighbour, rel)
            if len(indices) < MIN_INLIERS:
                continue
            if matched is None:
                matched = _matches(place, view)
            in_place, in_view = matched
            known = np.isin(in_place, indices)
            if known.sum() < MIN_INLIERS:
                continue
            world = points[np.searchsorted(indices, in_place[known])]
            pixels = view.points[in_view[known]]
            found, rvec, tvec, inliers = cv2.solvePnPRansac(
                world.astype(np.float32),
                pixels.astype(np.float32),
                self._k,
                None,
                reprojectionError=REPROJECTION_PX,
                iterationsCount=200,
                flags=cv2.SOLVEPNP_EPNP,
            )
            if not found or inliers is None or len(inliers) < MIN_INLIERS:
                continue
            rotation, _ = cv2.Rodrigues(rvec)
            camera_in_place = -rotation.T @ tvec.ravel()  # the view's camera centre, place camera frame
            planar = _ROBOT_TO_CAMERA.T @ camera_in_place
            distance = math.hypot(float(planar[0]), float(planar[1]))
            if best is None or len(inliers) > best[0]:
                best = (len(inliers), distance)
        return None if best is None else best[1]

    def _points(
        self,
        place_id: int,
        place: ViewFeatures,
        neighbour_id: int,
        neighbour: ViewFeatures,
        rel: tuple[float, float, float],
    ) -> tuple[np.ndarray, np.ndarray]:
        """(sorted indices into the place's features, (n, 3) points in the place's camera frame, metres)."""
        key = (place_id, neighbour_id)
        if key in self._triangulated:
            self._triangulated.move_to_end(key)
            return self._triangulated[key]
        result = self._triangulate(place, neighbour, rel)
        self._triangulated[key] = result
        if len(self._triangulated) > TRIANGULATED_CACHE:
            self._triangulated.popitem(last=False)
        return result

    def _triangulate(
        self, place: ViewFeatures, neighbour: ViewFeatures, rel: tuple[float, float, float]
    ) -> tuple[np.ndarray, np.ndarray]:
        import cv2

        empty = (np.zeros(0, np.int64), np.zeros((0, 3)))
        in_place, in_neighbour = _matches(place, neighbour)
        if len(in_place) < MIN_MATCHES:
            return empty
        rotation, translation = _camera_motion(rel)  # X_place = R X_neighbour + t
        k = self._k
        first = k @ np.hstack([np.eye(3), np.zeros((3, 1))])
        second = k @ np.hstack([rotation.T, (-rotation.T @ translation)[:, None]])
        a, b = place.points[in_place], neighbour.points[in_neighbour]
        homogeneous = cv2.triangulatePoints(first, second, a.T.astype(np.float64), b.T.astype(np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            points = (homogeneous[:3] / homogeneous[3]).T
            seen = (rotation.T @ (points - translation).T).T
            ok = (points[:, 2] > DEPTH_M[0]) & (seen[:, 2] > DEPTH_M[0]) & (points[:, 2] < DEPTH_M[1])
            ok &= _reprojection(k, points, a) < REPROJECTION_PX
            ok &= _reprojection(k, seen, b) < REPROJECTION_PX
        ok &= np.isfinite(points).all(axis=1)
        if not ok.any():
            return empty
        # One point per place feature (a feature matched twice keeps its first), sorted by index.
        indices, first_of = np.unique(in_place[ok], return_index=True)
        return indices, points[ok][first_of]


def _reprojection(k: np.ndarray, points: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    projected = (k @ points.T).T
    return np.linalg.norm(projected[:, :2] / projected[:, 2:3] - pixels, axis=1)
