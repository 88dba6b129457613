"""The pose graph over watchtowers, floor tags and robot tags, and its two solvers (GTSAM, SciPy).

Vertices (SE(3) poses in the map frame): each watchtower (a prior from its calibration, with the calibration's
stated uncertainty), each floor or ground tag (a tight prior at its known pose: it is the map's reference), and
each robot's roof tag at every time a watchtower saw it. Edges: every detection, T_camera_tag with its covariance
(``detect.tag_pose``), between a watchtower and a tag; a roof tag's flatness (its z and tilt held to the roof,
``ROOF_TAG_Z``, flat); and between a robot's consecutive poses a loose random-walk prior (``MAX_SPEED`` ×
the time between them), which keeps a trajectory together without pulling it (a few cm against the tags' mm).

``solve_gtsam`` is the default: Levenberg–Marquardt on GTSAM's factor graph (the Autolab uses g2o, the same
method) and each robot pose's marginal covariance, the per-sample uncertainty of the localised trajectory.
``solve_scipy`` minimises the same residuals with SciPy's sparse least squares (no covariances); the benchmark
(benchmarks/bench_localization.py) compares the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from proxybench.domain.objects import ROOF_TAG_Z

__all__ = ["MAX_SPEED", "MAX_TURN", "Observation", "PoseGraph", "Solution", "solve_gtsam", "solve_scipy"]

#: the random-walk prior between a robot's consecutive poses: 1σ of its motion per second [m/s], [rad/s]
MAX_SPEED, MAX_TURN = 0.5, 3.0
#: how flat a roof tag is held: 1σ of its height [m] and tilt [rad]
ROOF_Z_SIGMA, ROOF_TILT_SIGMA = 0.003, math.radians(1.0)
#: how tightly a floor tag is held at its map pose [m], [rad]
FIXED_SIGMA = 1e-3
#: 1σ of what the flatness prior leaves free (heading, position): loose, yet not so loose that the system's
#: conditioning (against FIXED_SIGMA) breaks GTSAM's marginals
FREE_SIGMA = 10.0


@dataclass(frozen=True)
class Observation:
    """Watchtower ``tower`` saw ``target`` (``("tag", id)`` or ``("robot", name, k)``) at T_camera_tag ± ``cov``."""

    tower: str
    target: tuple
    T: np.ndarray
    cov: np.ndarray


@dataclass
class PoseGraph:
    """What the graph holds before it is solved (see the module docstring)."""

    towers: dict[str, tuple[np.ndarray, float, float]] = field(default_factory=dict)  # prior T, σ [m], σ [rad]
    fixed: dict[int, np.ndarray] = field(default_factory=dict)  # floor tag id -> T_map_tag
    robots: dict[str, np.ndarray] = field(default_factory=dict)  # robot -> (K,) sample times [s]
    observations: list[Observation] = field(default_factory=list)

    def initial(self) -> dict[tuple, np.ndarray]:
        """A first guess of every vertex: priors, and each robot sample from its first observation."""
        out: dict[tuple, np.ndarray] = {("tower", n): T for n, (T, _, _) in self.towers.items()}
        out.update({("tag", i): T for i, T in self.fixed.items()})
        for o in self.observations:
            if o.target[0] == "robot" and o.target not in out:
                out[o.target] = _flat(self.towers[o.tower][0] @ o.T)
        return out


@dataclass
class Solution:
    """Solved poses (T_map_x) by vertex, and for robot samples their (x, y, θ) covariance (3 × 3) where known."""

    poses: dict[tuple, np.ndarray]
    cov: dict[tuple, np.ndarray]
    iterations: int
    error: float


def _flat(T: np.ndarray) -> np.ndarray:
    """The pose held at the roof's height, flat, with its heading."""
    th = math.atan2(T[1, 0], T[0, 0])
    out = np.eye(4)
    out[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
    out[:3, 3] = (T[0, 3], T[1, 3], ROOF_TAG_Z)
    return out


def _robot_keys(graph: PoseGraph) -> list[tuple]:
    return [("robot", r, k) for r, times in graph.robots.items() for k in range(len(times))]


def _motion_sigmas(dt: float) -> np.ndarray:
    """1σ (rotation ×3, translation ×3) of a robot's motion over ``dt`` [s]: the random-walk prior."""
    r, t = max(MAX_TURN * dt, 1e-3), max(MAX_SPEED * dt, 1e-3)
    return np.array([r, r, r, t, t, t])


def _flat_sigmas() -> np.ndarray:
    """Prior of a roof tag's flatness: tight tilt and height, free heading and position."""
    return np.array([ROOF_TILT_SIGMA, ROOF_TILT_SIGMA, FREE_SIGMA, FREE_SIGMA, FREE_SIGMA, ROOF_Z_SIGMA])


def solve_gtsam(graph: PoseGraph, covariances: bool = True) -> Solution:
    """Levenberg–Marquardt on the graph with GTSAM; marginal (x, y, θ) covariance of every robot sample."""
    import gtsam

    keys: dict[tuple, int] = {}

    def key(v: tuple) -> int:
        return keys.setdefault(v, len(keys))

    g = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for v, T in graph.initial().items():
        values.insert(key(v), gtsam.Pose3(T))
    for name, (T, s_pos, s_ang) in graph.towers.items():
        sig = np.array([s_ang] * 3 + [s_pos] * 3)
        g.add(gtsam.PriorFactorPose3(key(("tower", name)), gtsam.Pose3(T), gtsam.noiseModel.Diagonal.Sigmas(sig)))
    tight = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)
    for i, T in graph.fixed.items():
        g.add(gtsam.PriorFactorPose3(key(("tag", i)), gtsam.Pose3(T), tight))
    flat = gtsam.noiseModel.Diagonal.Sigmas(_flat_sigmas())
    init = graph.initial()
    for r, times in graph.robots.items():
        for k in range(len(times)):
            v = ("robot", r, k)
            g.add(gtsam.PriorFactorPose3(key(v), gtsam.Pose3(_flat(init[v])), flat))
            if k:
                walk = gtsam.noiseModel.Diagonal.Sigmas(_motion_sigmas(times[k] - times[k - 1]))
                g.add(gtsam.BetweenFactorPose3(key(("robot", r, k - 1)), key(v), gtsam.Pose3(), walk))
    for o in graph.observations:
        model = gtsam.noiseModel.Gaussian.Covariance(o.cov)
        g.add(gtsam.BetweenFactorPose3(key(("tower", o.tower)), key(o.target), gtsam.Pose3(o.T), model))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    opt = gtsam.LevenbergMarquardtOptimizer(g, values, params)
    result = opt.optimize()
    poses = {v: result.atPose3(k).matrix() for v, k in keys.items()}
    cov: dict[tuple, np.ndarray] = {}
    try:
        marg = gtsam.Marginals(g, result) if covariances else None
    except RuntimeError:  # an ill-conditioned system: poses without covariances (σ NaN), never a crash
        marg = None
    if marg is not None:
        for v in _robot_keys(graph):
            c = marg.marginalCovariance(keys[v])  # tangent (rot, trans) in the tag's own frame
            R = poses[v][:3, :3]
            J = np.zeros((3, 6))
            J[:2, 3:] = R[:2, :]  # world x, y from the body translation
            J[2, :3] = R[2, :]  # heading from the body rotation (about the world's z)
            cov[v] = J @ c @ J.T
    return Solution(poses, cov, opt.iterations(), float(g.error(result)))


# -- SciPy -----------------------------------------------------------------------------------------------


def _exp(xi: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses of (N, 6) vectors (rotation vector, translation), a rotation-then-translation chart."""
    from scipy.spatial.transform import Rotation

    out = np.tile(np.eye(4), (len(xi), 1, 1))
    out[:, :3, :3] = Rotation.from_rotvec(xi[:, :3]).as_matrix()
    out[:, :3, 3] = xi[:, 3:]
    return out


def _log(T: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return np.concatenate([Rotation.from_matrix(T[:, :3, :3]).as_rotvec(), T[:, :3, 3]], axis=1)


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.tile(np.eye(4), (len(T), 1, 1))
    Rt = np.transpose(T[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    return out


def solve_scipy(graph: PoseGraph) -> Solution:
    """The same graph by ``scipy.optimize.least_squares`` (trust region, sparse finite-difference Jacobian):
    each vertex is a correction δ of its first guess (T = T₀ · exp(δ)), each factor's residual its whitened
    error, as GTSAM's. No covariances."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    init = graph.initial()
    verts = list(init)
    index = {v: i for i, v in enumerate(verts)}
    T0 = np.stack([init[v] for v in verts])
    factors: list[tuple[int, int, np.ndarray, np.ndarray]] = []  # (i, j or -1, Z (i→j) or prior, whitening)

    def add(i: int, j: int, Z: np.ndarray, cov: np.ndarray) -> None:
        factors.append((i, j, Z, np.linalg.cholesky(np.linalg.inv(cov)).T))

    for name, (T, s_pos, s_ang) in graph.towers.items():
        add(index[("tower", name)], -1, T, np.diag(np.array([s_ang] * 3 + [s_pos] * 3) ** 2))
    for i, T in graph.fixed.items():
        add(index[("tag", i)], -1, T, np.eye(6) * FIXED_SIGMA ** 2)
    for r, times in graph.robots.items():
        for k in range(len(times)):
            v = index[("robot", r, k)]
            add(v, -1, _flat(init[("robot", r, k)]), np.diag(_flat_sigmas() ** 2))
            if k:
                add(index[("robot", r, k - 1)], v, np.eye(4), np.diag(_motion_sigmas(times[k] - times[k - 1]) ** 2))
    for o in graph.observations:
        add(index[("tower", o.tower)], index[o.target], o.T, o.cov)
    fi = np.array([f[0] for f in factors])
    fj = np.array([f[1] for f in factors])
    Z = np.stack([f[2] for f in factors])
    W = np.stack([f[3] for f in factors])
    prior = fj < 0
    Zinv = _inv(Z)

    def residuals(x: np.ndarray) -> np.ndarray:
        T = T0 @ _exp(x.reshape(-1, 6))
        a = T[fi]
        b = np.where(prior[:, None, None], np.eye(4), T[np.maximum(fj, 0)])
        rel = np.where(prior[:, None, None], a, _inv(a) @ b)  # prior: the vertex itself; between: a⁻¹ b
        err = _log(Zinv @ rel)
        return np.einsum("nij,nj->ni", W, err).ravel()

    sparsity = lil_matrix((6 * len(factors), 6 * len(verts)), dtype=np.int8)
    for n, (i, j) in enumerate(zip(fi, fj, strict=True)):
        sparsity[6 * n: 6 * n + 6, 6 * i: 6 * i + 6] = 1
        if j >= 0:
            sparsity[6 * n: 6 * n + 6, 6 * j: 6 * j + 6] = 1
    res = least_squares(residuals, np.zeros(6 * len(verts)), jac_sparsity=sparsity, method="trf", x_scale="jac",
                        max_nfev=50)
    T = T0 @ _exp(res.x.reshape(-1, 6))
    return Solution({v: T[index[v]] for v in verts}, {}, int(res.nfev), float(0.5 * np.sum(res.fun ** 2)))
