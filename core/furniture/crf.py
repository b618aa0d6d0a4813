"""A pairwise log-linear CRF over segments: node weights on features, edge weights per
(relation, label, label); trained by maximum pseudo-likelihood (L-BFGS) and decoded by loopy
max-product belief propagation. :func:`binned` encodes scalar features for it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
    def fit(
        self, graphs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], l2: float = 1.0, edge_l2: float = 1.0
    ) -> CRF:
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

    def predict(
        self, X: np.ndarray, E: np.ndarray, rel: np.ndarray, iterations: int = 30, damping: float = 0.5
    ) -> np.ndarray:
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
        return {
            "labels": list(self.labels),
            "n_features": self.n_features,
            "n_relations": self.n_relations,
            "node_weights": self.node_weights.round(6).tolist(),
            "edge_weights": self.edge_weights.round(6).tolist(),
        }

    @classmethod
    def from_dict(cls, doc: dict) -> CRF:
        return cls(
            tuple(doc["labels"]),
            int(doc["n_features"]),
            int(doc["n_relations"]),
            np.asarray(doc["node_weights"]),
            np.asarray(doc["edge_weights"]),
        )
