"""AprilTag detection in a watchtower's frames and each tag's pose relative to the camera, with its uncertainty.

Two maintained detectors read tag36h11: the AprilTag 3 library through ``pupil-apriltags`` (``apriltag``, the
default: the Duckietown stack's own detector is a fork of it) and OpenCV's ArUco module (``aruco``). Both give
each tag's four image corners, which are put in one order (the marker's top left, top right, bottom right,
bottom left) and one pixel convention (OpenCV's: pixel centres at integer coordinates).

A tag's pose in the camera, T_camera_tag, comes from its corners, its size and the watchtower's calibration
(``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE``). A small tag seen from afar has two poses that fit its
corners almost equally (mirror images in tilt); tags lie flat (on the floor, on a robot's roof), so of the two
the one whose face points up in the map frame is kept, given the watchtower's calibrated orientation. Its
covariance is the corner noise (``CORNER_SIGMA`` [px]) carried through the projection's Jacobian
(σ² (JᵀJ)⁻¹, 6 × 6 over rotation then translation in the tag's frame), so a tag seen at a slant or at a
distance counts for less in the pose graph.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from proxybench.autolab.calibration import Calibration
from proxybench.autolab.geometry import tag_corners

__all__ = ["CORNER_SIGMA", "DETECTORS", "Detection", "Detector", "TagPose", "tag_pose"]

#: 1σ of a detected corner [px] (sub-pixel refined corners of a sharp tag)
CORNER_SIGMA = 0.3
DETECTORS = ("apriltag", "aruco")


@dataclass(frozen=True)
class Detection:
    """One tag in one frame: its id and (4, 2) corners [px] (top left, top right, bottom right, bottom left)."""

    tag_id: int
    corners: np.ndarray


@dataclass(frozen=True)
class TagPose:
    """T_camera_tag (4 × 4) and its 6 × 6 covariance (rotation [rad], then translation [m], tag frame)."""

    tag_id: int
    T: np.ndarray
    cov: np.ndarray
    pixels: float  # the tag's edge in the image [px], a measure of how well it is seen


#: pupil-apriltags detectors by decimation, made once per process (a detector's tables take a while to build)
_PUPIL: dict[float, object] = {}
#: one maker at a time: two threads (the online detector's worker and the main thread) making one decimation's
#: detector at once would make two, and drop one
_PUPIL_LOCK = threading.Lock()


def pupil_detector_class() -> type:
    """pupil-apriltags' ``Detector`` with its destructor in the right order.

    pupil-apriltags (1.0.4.post11) frees the tag families first and the detector after, but destroying the
    detector walks its families (``quick_decode_uninit``): a use after free that crashed evaluator workers now
    and then (SIGSEGV from the garbage collector) and always with glibc's ``MALLOC_PERTURB_``. AprilTag's own
    example, and duckietown/lib-dt-apriltags#26, destroy the detector first; so does this."""
    try:
        from pupil_apriltags import Detector as _Pupil
    except ImportError as exc:
        raise ImportError("the apriltag detector needs pupil-apriltags: pip install 'proxybench[autolab]'") from exc

    class PupilDetector(_Pupil):
        def __del__(self) -> None:
            ptr = getattr(self, "tag_detector_ptr", None)
            if ptr is None:  # never made, or already destroyed
                return
            self.tag_detector_ptr = None
            self.libc.apriltag_detector_destroy.restype = None
            self.libc.apriltag_detector_destroy(ptr)
            for family, tf in self.tag_families.items():
                destroy = getattr(self.libc, f"{family}_destroy")
                destroy.restype = None
                destroy(tf)

    return PupilDetector


def _pupil(decimate: float):
    with _PUPIL_LOCK:
        if decimate not in _PUPIL:
            _PUPIL[decimate] = pupil_detector_class()(families="tag36h11", nthreads=1, quad_decimate=decimate,
                                                      refine_edges=1)
        return _PUPIL[decimate]


class Detector:
    """A tag36h11 detector: ``Detector('apriltag')`` (pupil-apriltags) or ``Detector('aruco')`` (OpenCV)."""

    def __init__(self, kind: str = "apriltag", decimate: float = 1.0):
        if kind not in DETECTORS:
            raise ValueError(f"detector must be one of {', '.join(DETECTORS)}, got {kind!r}")
        self.kind = kind
        if kind == "apriltag":
            self._det = _pupil(decimate)
        else:
            import cv2

            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
            self._det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11),
                                                params)

    def detect(self, gray: np.ndarray) -> list[Detection]:
        """The tags in a (H, W) uint8 image."""
        if self.kind == "apriltag":
            # AprilTag's corners run (bottom left, bottom right, top right, top left) of the tag's own frame, which
            # is the printed marker's (top right, top left, bottom left, bottom right), with pixel centres at +0.5
            return [Detection(int(d.tag_id), np.asarray(d.corners, dtype=np.float64)[[1, 0, 3, 2]] - 0.5)
                    for d in self._det.detect(np.ascontiguousarray(gray))]
        corners, ids, _ = self._det.detectMarkers(gray)
        if ids is None:
            return []
        return [Detection(int(i), np.asarray(c, dtype=np.float64).reshape(4, 2)) for c, i in zip(corners, ids.ravel(),
                                                                                                   strict=True)]


def _undistorted(cal: Calibration, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, K, D) for solvePnP: an equidistant lens is undone here (solvePnP knows only plumb-bob)."""
    import cv2

    if cal.distortion_model == "equidistant":
        norm = cv2.fisheye.undistortPoints(pts.reshape(-1, 1, 2), cal.K, cal.D[:4]).reshape(-1, 2)
        return norm, np.eye(3), np.zeros(5)
    d = np.zeros(5) if cal.distortion_model == "none" else cal.D
    return pts, cal.K, d


def tag_pose(det: Detection, size: float, cal: Calibration, up_in_camera: np.ndarray) -> TagPose | None:
    """T_camera_tag of a detection of a tag of edge ``size`` [m] lying flat; ``up_in_camera``: the map's up
    axis in the camera frame (from the calibration). None where no pose fits."""
    import cv2

    obj = tag_corners(size)
    pts, K, D = _undistorted(cal, det.corners)
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, pts.reshape(-1, 1, 2), K, D, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    except cv2.error:
        return None
    best, best_up = None, -2.0
    for rv, tv in zip(rvecs[:n], tvecs[:n], strict=True):
        R, _ = cv2.Rodrigues(rv)
        up = float(R[:, 2] @ up_in_camera)  # the tag's face normal against the map's up
        if up > best_up and float(tv[2, 0]) > 0:
            best, best_up = (R, tv.ravel()), up
    if best is None or best_up < 0.5:
        return None
    R, t = best
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    J = _jacobian(obj, R, t, K, D)
    normalised = cal.distortion_model == "equidistant"  # the corners were undone to normalised coordinates
    sigma = CORNER_SIGMA / cal.K[0, 0] if normalised else CORNER_SIGMA
    info = J.T @ J / sigma ** 2
    try:
        cov = np.linalg.inv(info + 1e-12 * np.eye(6))
    except np.linalg.LinAlgError:
        return None
    edge = float(np.mean(np.linalg.norm(det.corners - np.roll(det.corners, 1, axis=0), axis=1)))
    return TagPose(det.tag_id, T, 0.5 * (cov + cov.T), edge)


def _jacobian(obj: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(8, 6) derivative of the projected corners by a small motion of the tag (rotation, translation in its
    own frame: T · exp(δ)), numerically."""
    import cv2

    def project(delta: np.ndarray) -> np.ndarray:
        dR, _ = cv2.Rodrigues(delta[:3])
        pts = (obj @ dR.T + delta[3:]) @ R.T + t
        img, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)
        return img.reshape(-1)

    eps = 1e-6
    base = project(np.zeros(6))
    J = np.empty((8, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        J[:, k] = (project(d) - base) / eps
    return J
