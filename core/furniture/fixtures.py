"""Handles and knobs on furniture faces: handles as 3D line segments, knobs as circles, by RANSAC
then a Levenberg-Marquardt refinement (``scipy.optimize.least_squares(method="lm")``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.furniture.faces import plane_axes, radius_components
from stratamap.core.lazy import lazy_module

spatial = lazy_module("scipy.spatial")


@dataclass
class Fixture:
    kind: str  # handle | knob
    center: np.ndarray  # world
    direction: np.ndarray | None = None  # handles: unit axis
    length: float = 0.0
    radius: float = 0.0
    points: int = 0


def fit_line(
    points: np.ndarray, threshold: float = 0.01, iterations: int = 100, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3D line by RANSAC then LM on the orthogonal distances: (point on the line, unit direction, inlier mask)."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(seed)
    best, best_n = None, -1
    for a, b in rng.integers(0, len(points), size=(iterations, 2)):
        d = points[b] - points[a]
        if np.linalg.norm(d) < 1e-6:
            continue
        d /= np.linalg.norm(d)
        r = np.linalg.norm(np.cross(points - points[a], d), axis=1)
        n = int((r < threshold).sum())
        if n > best_n:
            best_n, best = n, (points[a].copy(), d)
    if best is None:
        c = points.mean(0)
        return c, np.array([1.0, 0.0, 0.0]), np.ones(len(points), bool)
    p0, d0 = best
    inl = np.linalg.norm(np.cross(points - p0, d0), axis=1) < threshold
    pts = points[inl]
    # parametrize by a point and the direction's spherical angles
    theta0, phi0 = np.arccos(np.clip(d0[2], -1, 1)), np.arctan2(d0[1], d0[0])

    def residual(x: np.ndarray) -> np.ndarray:
        p, (t, f) = x[:3], x[3:]
        d = np.array([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)])
        return np.linalg.norm(np.cross(pts - p, d), axis=1)

    if len(pts) >= 6:
        sol = least_squares(residual, np.r_[pts.mean(0), theta0, phi0], method="lm")
        p0, (t, f) = sol.x[:3], sol.x[3:]
        d0 = np.array([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)])
    inl = np.linalg.norm(np.cross(points - p0, d0), axis=1) < threshold
    return p0, d0 / np.linalg.norm(d0), inl


def fit_circle(uv: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Circle in 2D (a knob seen on the face plane): algebraic fit then LM; (centre, radius, rms)."""
    from scipy.optimize import least_squares

    A = np.c_[2 * uv, np.ones(len(uv))]
    b = (uv**2).sum(1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c0 = sol[:2]
    r0 = float(np.sqrt(max(sol[2] + c0 @ c0, 1e-12)))
    if len(uv) >= 4:
        res = least_squares(lambda x: np.linalg.norm(uv - x[:2], axis=1) - x[2], np.r_[c0, r0], method="lm")
        c0, r0 = res.x[:2], abs(float(res.x[2]))
    rms = float(np.sqrt(np.mean((np.linalg.norm(uv - c0, axis=1) - r0) ** 2)))
    return c0, r0, rms


def find_fixtures(
    face_points: np.ndarray,
    normal: np.ndarray,
    d: float,
    cloud: np.ndarray,
    tree: spatial.cKDTree,
    standoff: tuple[float, float] = (0.012, 0.07),
    cluster_radius: float = 0.02,
    min_points: int = 8,
    max_handle: float = 0.6,
) -> list[Fixture]:
    """Handles and knobs standing off a vertical face: points of ``cloud`` in front of the plane
    (``standoff`` metres along its normal) inside the face's outline, clustered; elongated
    clusters up to ``max_handle`` long are handles (line fit), compact ones knobs (circle fit)."""
    if len(face_points) < 10:
        return []
    u, v = plane_axes(normal)
    fu, fv = face_points @ u, face_points @ v
    center = face_points.mean(0)
    reach = float(np.hypot(np.ptp(fu), np.ptp(fv))) / 2 + standoff[1]
    near = np.asarray(tree.query_ball_point(center, reach), dtype=np.int64)
    if len(near) == 0:
        return []
    pts = cloud[near]
    h = pts @ normal + d
    pu, pv = pts @ u, pts @ v
    inside = (pu >= fu.min()) & (pu <= fu.max()) & (pv >= fv.min()) & (pv <= fv.max())
    sel = pts[(h > standoff[0]) & (h < standoff[1]) & inside]
    if len(sel) < min_points:
        return []
    comp = radius_components(sel, cluster_radius)
    out: list[Fixture] = []
    for c in np.unique(comp):
        cp = sel[comp == c]
        if len(cp) < min_points:
            continue
        uv = np.stack([cp @ u, cp @ v], 1)
        ext = np.ptp(uv, axis=0)
        long_side = float(ext.max())
        if long_side > max_handle:  # a counter top's edge or a rail, not something to pull
            continue
        if long_side >= 0.06 and long_side >= 2.5 * max(float(ext.min()), 0.005):
            p0, dvec, inl = fit_line(cp)
            t = (cp[inl] - p0) @ dvec if inl.any() else (cp - p0) @ dvec
            mid = p0 + dvec * (t.max() + t.min()) / 2
            out.append(Fixture("handle", mid, dvec, float(np.ptp(t)), 0.0, len(cp)))
        elif long_side <= 0.07:
            c2, r, _ = fit_circle(uv)
            depth = float(np.median(cp @ normal + d))
            ctr = c2[0] * u + c2[1] * v - d * normal + depth * normal
            out.append(Fixture("knob", ctr, None, 0.0, r, len(cp)))
    return out
