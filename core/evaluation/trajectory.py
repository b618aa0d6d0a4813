"""Trajectory error against ground truth (Sturm et al., TUM RGB-D benchmark): ATE and RPE."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> np.ndarray:
    """The similarity (rotation, translation[, scale]) that best maps ``source`` points onto ``target``."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    cov = (target - mu_t).T @ (source - mu_s) / len(source)
    u, d, vt = np.linalg.svd(cov)
    s = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2, 2] = -1
    r = u @ s @ vt
    scale = 1.0
    if with_scale:
        var = ((source - mu_s) ** 2).sum() / len(source)
        scale = float(np.trace(np.diag(d) @ s) / var) if var > 0 else 1.0
    t = mu_t - scale * r @ mu_s
    out = np.eye(4)
    out[:3, :3] = scale * r
    out[:3, 3] = t
    return out


def ate(estimated: Sequence[np.ndarray], ground_truth: Sequence[np.ndarray]) -> dict[str, float]:
    """Absolute trajectory error (RMSE of positions after rigid alignment), metres."""
    est = np.array([p[:3, 3] for p in estimated])
    gt = np.array([p[:3, 3] for p in ground_truth])
    if len(est) != len(gt) or len(est) == 0:
        raise ValueError(f"ATE needs equally many poses, got {len(est)} and {len(gt)}")
    align = umeyama(est, gt) if len(est) >= 3 else np.eye(4)
    err = np.linalg.norm(est @ align[:3, :3].T + align[:3, 3] - gt, axis=1)
    return {
        "ate_rmse_m": float(np.sqrt(np.mean(err**2))),
        "ate_mean_m": float(err.mean()),
        "ate_max_m": float(err.max()),
    }


def rpe(estimated: Sequence[np.ndarray], ground_truth: Sequence[np.ndarray], delta: int = 1) -> dict[str, float]:
    """Relative pose error over ``delta`` frames: RMSE of translation (m) and rotation (deg)."""
    trans, rot = [], []
    for i in range(len(estimated) - delta):
        de = np.linalg.inv(estimated[i]) @ estimated[i + delta]
        dg = np.linalg.inv(ground_truth[i]) @ ground_truth[i + delta]
        e = np.linalg.inv(dg) @ de
        trans.append(np.linalg.norm(e[:3, 3]))
        rot.append(np.degrees(np.arccos(np.clip((np.trace(e[:3, :3]) - 1) / 2, -1, 1))))
    if not trans:
        return {"rpe_trans_rmse_m": 0.0, "rpe_rot_rmse_deg": 0.0}
    return {
        "rpe_trans_rmse_m": float(np.sqrt(np.mean(np.square(trans)))),
        "rpe_rot_rmse_deg": float(np.sqrt(np.mean(np.square(rot)))),
    }
