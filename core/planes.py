"""Planar decomposition of indoor scans, fixtures on furniture faces, and a small CRF.

The algorithms of the kitchen paper (semantic 3D object maps of kitchens):

* :func:`multilod_planes` -- planes found by MSAC with sampling localized in octree cells, from
  the coarsest level to the finest (big planes first, then what is left in smaller cells); each
  plane found in a cell is refined by growing its support over the neighbouring cells and
  refitting (least squares), and coplanar neighbours are merged at the end.
* :func:`boundary_points` and :func:`region_grow` -- each plane's inliers split into connected
  regions; boundary points (an angular gap in their in-plane neighbourhood) stop the growth.
* :func:`fit_line` and :func:`fit_circle` -- handles as 3D line segments and knobs as circles, by
  RANSAC then a Levenberg-Marquardt refinement (``scipy.optimize.least_squares(method="lm")``).
* :class:`CRF` -- a pairwise log-linear CRF over segments: node weights on features, edge
  weights per (relation, label, label); trained by maximum pseudo-likelihood (L-BFGS) and
  decoded by loopy max-product belief propagation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from stratamap.core.geometry import cell_keys


# --------------------------------------------------------------------------------------------
# Planes


@dataclass
class Plane:
    normal: np.ndarray  # unit, oriented to +z for horizontal planes
    d: float  # n . x + d = 0
    indices: np.ndarray  # point indices


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    n = vt[2]
    if n[2] < 0 or (abs(n[2]) < 1e-9 and n[0] < 0):
        n = -n
    return n, float(-n @ c)


def _msac(points: np.ndarray, normals: np.ndarray, threshold: float, normal_cos: float, iterations: int, rng: np.random.Generator, chunk: int = 32) -> tuple[np.ndarray, float, np.ndarray] | None:
    """MSAC: the plane minimizing the truncated quadratic loss; inliers also agree in normal."""
    n_pts = len(points)
    if n_pts < 3:
        return None
    s = rng.integers(0, n_pts, size=(iterations, 3))
    nrm = np.cross(points[s[:, 1]] - points[s[:, 0]], points[s[:, 2]] - points[s[:, 0]])
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 1e-9
    nrm = nrm[ok] / length[ok, None]
    anchor = points[s[ok, 0]]
    agree = np.abs(np.einsum("ij,ij->i", nrm, normals[s[ok, 0]])) >= normal_cos  # the sample's own normal must agree
    nrm, anchor = nrm[agree], anchor[agree]
    if len(nrm) == 0:
        return None
    offs = -np.einsum("ij,ij->i", nrm, anchor)
    t2 = threshold * threshold
    costs = np.empty(len(nrm))
    for a in range(0, len(nrm), chunk):
        r = points @ nrm[a : a + chunk].T + offs[a : a + chunk]  # (N, c)
        c = np.minimum(r * r, t2)
        c[np.abs(normals @ nrm[a : a + chunk].T) < normal_cos] = t2
        costs[a : a + chunk] = c.sum(0)
    k = int(np.argmin(costs))
    n, d = nrm[k], float(offs[k])
    inl = np.flatnonzero((np.abs(points @ n + d) < threshold) & (np.abs(normals @ n) >= normal_cos))
    if len(inl) < 3:
        return None
    n, d = _fit_plane(points[inl])
    inl = np.flatnonzero((np.abs(points @ n + d) < threshold) & (np.abs(normals @ n) >= normal_cos))
    return n, d, inl


def multilod_planes(
    points: np.ndarray,
    normals: np.ndarray,
    cell_sizes: tuple[float, ...] = (2.0, 1.0, 0.5),
    threshold: float = 0.02,
    normal_deg: float = 25.0,
    min_points: int = 60,
    iterations: int = 150,
    merge_deg: float = 5.0,
    merge_offset: float = 0.02,
    adjacency: float = 0.05,
    seed: int = 0,
) -> list[Plane]:
    """Planes by octree-localized MSAC, coarse to fine; see the module doc."""
    rng = np.random.default_rng(seed)
    normal_cos = float(np.cos(np.radians(normal_deg)))
    free = np.ones(len(points), bool)
    planes: list[Plane] = []
    for size in cell_sizes:
        keys = np.floor(points / size).astype(np.int64)
        flat = cell_keys(points, size)
        changed = True
        while changed:
            changed = False
            idx_free = np.flatnonzero(free)
            if len(idx_free) < min_points:
                break
            _, first, inverse, counts = np.unique(flat[idx_free], return_index=True, return_inverse=True, return_counts=True)
            cells = keys[idx_free[first]]
            inverse = inverse.reshape(-1)
            order = np.lexsort((np.arange(len(cells)), -counts))  # fullest cells first (deterministic)
            for ci in order:
                if counts[ci] < min_points:
                    break
                members = idx_free[inverse == ci]
                members = members[free[members]]
                if len(members) < min_points:
                    continue
                found = _msac(points[members], normals[members], threshold, normal_cos, iterations, rng)
                if found is None or len(found[2]) < min_points:
                    continue
                nrm, d, _ = found
                # refine: grow the plane over the 3x3x3 neighbouring cells and refit, twice
                near = np.flatnonzero(free & np.all(np.abs(keys - cells[ci]) <= 1, axis=1))
                for _ in range(2):
                    ok = (np.abs(points[near] @ nrm + d) < threshold) & (np.abs(normals[near] @ nrm) >= normal_cos)
                    if ok.sum() < 3:
                        break
                    nrm, d = _fit_plane(points[near[ok]])
                inl = near[(np.abs(points[near] @ nrm + d) < threshold) & (np.abs(normals[near] @ nrm) >= normal_cos)]
                inl = _largest_components(points, inl, adjacency, min_points)
                if len(inl) < min_points:
                    continue
                planes.append(Plane(nrm, d, inl))
                free[inl] = False
                changed = True
    return merge_planes(points, planes, merge_deg, merge_offset, adjacency)


def _largest_components(points: np.ndarray, idx: np.ndarray, radius: float, min_points: int) -> np.ndarray:
    """The connected pieces (within ``radius``) of ``idx`` that have at least ``min_points``."""
    if len(idx) == 0:
        return idx
    comp = _components(points[idx], radius)
    sizes = np.bincount(comp)
    return idx[sizes[comp] >= min_points]


def _components(points: np.ndarray, radius: float) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    n = len(points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else coo_matrix((n, n))
    return connected_components(graph, directed=False)[1]


def merge_planes(points: np.ndarray, planes: list[Plane], merge_deg: float, merge_offset: float, adjacency: float) -> list[Plane]:
    """Union of planes that are parallel (``merge_deg``), at the same offset and touching."""
    if len(planes) < 2:
        return planes
    parent = list(range(len(planes)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    trees = [cKDTree(points[p.indices]) for p in planes]
    cos = np.cos(np.radians(merge_deg))
    for i in range(len(planes)):
        for j in range(i + 1, len(planes)):
            a, b = planes[i], planes[j]
            if abs(a.normal @ b.normal) < cos:
                continue
            ci, cj = points[a.indices].mean(0), points[b.indices].mean(0)
            if abs(a.normal @ cj + a.d) > merge_offset or abs(b.normal @ ci + b.d) > merge_offset:
                continue
            if trees[i].count_neighbors(trees[j], adjacency) == 0:
                continue
            parent[find(j)] = find(i)
    groups: dict[int, list[int]] = {}
    for i in range(len(planes)):
        groups.setdefault(find(i), []).append(i)
    out = []
    for members in groups.values():
        idx = np.sort(np.concatenate([planes[m].indices for m in members]))
        n, d = _fit_plane(points[idx]) if len(members) > 1 else (planes[members[0]].normal, planes[members[0]].d)
        out.append(Plane(n, d, idx))
    return out


def plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two in-plane unit axes: for vertical planes, horizontal then +z; otherwise any pair."""
    n = normal / np.linalg.norm(normal)
    up = np.array([0.0, 0.0, 1.0])
    if abs(n[2]) < 0.9:
        u = np.cross(up, n)
        u /= np.linalg.norm(u)
        return u, np.cross(n, u)
    u = np.cross(n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def boundary_points(points: np.ndarray, normal: np.ndarray, radius: float, k: int = 12, gap_deg: float = 90.0) -> np.ndarray:
    """Points whose in-plane neighbours leave an angular gap wider than ``gap_deg`` (PCL's
    boundary estimation): the rim of a surface, where region growing must stop."""
    n = len(points)
    if n < 4:
        return np.ones(n, bool)
    u, v = plane_axes(normal)
    uv = np.stack([points @ u, points @ v], 1)
    dist, nb = cKDTree(uv).query(uv, k=min(k + 1, n), distance_upper_bound=radius)
    nb = nb[:, 1:]
    valid = np.isfinite(dist[:, 1:])
    safe = np.where(valid, nb, 0)
    delta = uv[safe] - uv[:, None, :]
    ang = np.sort(np.where(valid, np.arctan2(delta[..., 1], delta[..., 0]), 100.0), axis=1)  # invalid last
    count = valid.sum(1)
    gaps = np.diff(ang, axis=1)
    gaps = np.where(np.arange(gaps.shape[1])[None, :] + 1 < count[:, None], gaps, 0.0)
    first = ang[:, 0]
    last = np.take_along_axis(ang, np.maximum(count - 1, 0)[:, None], 1)[:, 0]
    wrap = np.where(count > 0, 2 * np.pi - (last - first), 2 * np.pi)
    widest = np.maximum(gaps.max(axis=1) if gaps.shape[1] else 0.0, wrap)
    return (count < 3) | (widest > np.radians(gap_deg))


def region_grow(points: np.ndarray, boundary: np.ndarray, radius: float) -> np.ndarray:
    """Regions of one plane's inliers: interior points connect within ``radius``; boundary
    points stop the growth and join their nearest interior region. Labels 0..R-1."""
    inner = np.flatnonzero(~boundary)
    labels = np.zeros(len(points), np.int64)
    if len(inner) == 0:
        return labels
    labels[inner] = _components(points[inner], radius)
    if boundary.any():
        _, nearest = cKDTree(points[inner]).query(points[boundary])
        labels[boundary] = labels[inner][nearest]
    return labels


# --------------------------------------------------------------------------------------------
# Fixtures


@dataclass
class Fixture:
    kind: str  # handle | knob
    center: np.ndarray  # world
    direction: np.ndarray | None = None  # handles: unit axis
    length: float = 0.0
    radius: float = 0.0
    points: int = 0


def fit_line(points: np.ndarray, threshold: float = 0.01, iterations: int = 100, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    face_points: np.ndarray, normal: np.ndarray, d: float, cloud: np.ndarray, tree: cKDTree,
    standoff: tuple[float, float] = (0.012, 0.07), cluster_radius: float = 0.02, min_points: int = 8, max_handle: float = 0.6,
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
    comp = _components(sel, cluster_radius)
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


# --------------------------------------------------------------------------------------------
# Features

def binned(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Triangular (linear-interpolation) encoding of scalars on ``edges``: (N, len(edges))."""
    values = np.clip(np.asarray(values, float), edges[0], edges[-1])
    out = np.zeros((len(values), len(edges)))
    k = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)
    w = (values - edges[k]) / (edges[k + 1] - edges[k])
    out[np.arange(len(values)), k] = 1 - w
    out[np.arange(len(values)), k + 1] = w
    return out


# --------------------------------------------------------------------------------------------
# CRF


@dataclass
class CRF:
    """Pairwise log-linear CRF: score(y) = sum_i W[y_i] . f_i + sum_(i,j) E[r_ij, y_i, y_j]."""

    labels: tuple[str, ...]
    n_features: int
    n_relations: int
    node_weights: np.ndarray = field(default=None)  # type: ignore[assignment]  # (L, F)
    edge_weights: np.ndarray = field(default=None)  # type: ignore[assignment]  # (R, L, L)

    def __post_init__(self) -> None:
        L = len(self.labels)
        if self.node_weights is None:
            self.node_weights = np.zeros((L, self.n_features))
        if self.edge_weights is None:
            self.edge_weights = np.zeros((self.n_relations, L, L))
        self.node_weights = np.asarray(self.node_weights, float).reshape(L, self.n_features)
        self.edge_weights = np.asarray(self.edge_weights, float).reshape(self.n_relations, L, L)

    # graphs: (features (N, F), undirected edges (E, 2) listed once, relation of the ordered pair (E,), labels (N,))
    def fit(self, graphs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], l2: float = 1.0, edge_l2: float = 1.0) -> CRF:
        """Maximum pseudo-likelihood with L2 priors (L-BFGS). Nodes labelled < 0 are left out,
        and so are their edges."""
        from scipy.optimize import minimize

        L, F, R = len(self.labels), self.n_features, self.n_relations
        data = []
        for X, E, rel, y in graphs:
            E = np.asarray(E, np.int64).reshape(-1, 2)
            keep = y >= 0
            if not keep.any():
                continue
            ok = keep[E[:, 0]] & keep[E[:, 1]] if len(E) else np.zeros(0, bool)
            data.append((X, E[ok], np.asarray(rel)[ok], y))

        def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
            W = theta[: L * F].reshape(L, F)
            P = theta[L * F :].reshape(R, L, L)
            nll, gW, gP = 0.0, np.zeros_like(W), np.zeros_like(P)
            for X, E, rel, y in data:
                s = X @ W.T  # (N, L)
                a, b = (E[:, 0], E[:, 1]) if len(E) else (np.zeros(0, int), np.zeros(0, int))
                if len(E):
                    np.add.at(s, a, P[rel, :, y[b]])
                    np.add.at(s, b, P[rel, y[a], :])
                keep = y >= 0
                m = s.max(1, keepdims=True)
                logz = m[:, 0] + np.log(np.exp(s - m).sum(1))
                p = np.exp(s - logz[:, None])
                idx = np.flatnonzero(keep)
                nll -= float((s[idx, y[idx]] - logz[idx]).sum())
                g = np.where(keep[:, None], p, 0.0)
                g[idx, y[idx]] -= 1.0  # d nll / d s
                gW += g.T @ X
                if len(E):
                    np.add.at(gP, (rel[:, None], np.arange(L)[None, :], y[b][:, None]), g[a])
                    np.add.at(gP, (rel[:, None], y[a][:, None], np.arange(L)[None, :]), g[b])
            nll += 0.5 * l2 * float((W**2).sum()) + 0.5 * edge_l2 * float((P**2).sum())
            gW += l2 * W
            gP += edge_l2 * P
            return nll, np.r_[gW.ravel(), gP.ravel()]

        x0 = np.r_[self.node_weights.ravel(), self.edge_weights.ravel()]
        res = minimize(objective, x0, jac=True, method="L-BFGS-B", options={"maxiter": 1000})
        self.node_weights = res.x[: L * F].reshape(L, F)
        self.edge_weights = res.x[L * F :].reshape(R, L, L)
        return self

    def node_scores(self, X: np.ndarray) -> np.ndarray:
        return X @ self.node_weights.T

    def predict(self, X: np.ndarray, E: np.ndarray, rel: np.ndarray, iterations: int = 30, damping: float = 0.5) -> np.ndarray:
        """Loopy max-product belief propagation (log domain, damped); exact on trees."""
        unary = self.node_scores(X)
        E = np.asarray(E, np.int64).reshape(-1, 2)
        if len(E) == 0:
            return unary.argmax(1)
        L = len(self.labels)
        src = np.r_[E[:, 0], E[:, 1]]
        dst = np.r_[E[:, 1], E[:, 0]]
        pot = np.concatenate([self.edge_weights[rel], self.edge_weights[rel].transpose(0, 2, 1)])  # [k, y_src, y_dst]
        rev = np.r_[np.arange(len(E)) + len(E), np.arange(len(E))]
        msgs = np.zeros((len(src), L))
        for _ in range(iterations):
            incoming = np.zeros_like(unary)
            np.add.at(incoming, dst, msgs)
            belief = unary[src] + incoming[src] - msgs[rev]
            new = (belief[:, :, None] + pot).max(axis=1)
            new -= new.max(1, keepdims=True)
            msgs = damping * msgs + (1 - damping) * new
        incoming = np.zeros_like(unary)
        np.add.at(incoming, dst, msgs)
        return (unary + incoming).argmax(1)

    def to_dict(self) -> dict:
        return {"labels": list(self.labels), "n_features": self.n_features, "n_relations": self.n_relations,
                "node_weights": self.node_weights.round(6).tolist(), "edge_weights": self.edge_weights.round(6).tolist()}

    @classmethod
    def from_dict(cls, doc: dict) -> CRF:
        return cls(tuple(doc["labels"]), int(doc["n_features"]), int(doc["n_relations"]), np.asarray(doc["node_weights"]), np.asarray(doc["edge_weights"]))
