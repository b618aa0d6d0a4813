"""Completer ``icp_match``: model matching by z-rotation sampling and ICP (augmented-representations
paper, section IV-B).

For each object of a class the library has:

1. rank the class's models by global descriptor and keep the top ``shortlist`` (or all);
2. coarse alignment: rotate the reference model (the best-ranked) about z in ``yaw_samples``
   uniform steps around the object's support point (each with a few translation-only ICP steps,
   since a partial view's centroid is not the model's); keep the rotation with the least mean
   point-to-point distance;
3. refine by ICP with yaw and translation only (the object stands on its support), height scale
   from the observed height within the heights plausible for the class (``core/map/priors.py``);
4. align every candidate from that pose (a few more ICP steps each) and score it by the one-sided
   distance from the observed points to the model surface (the observation is partial: unseen
   model parts cost nothing) plus a coverage term (how far the observation sticks out of the
   model's extent, so a tiny model cannot win by sitting inside the observation);
5. search the best model's width and depth scale per axis around its height scale (pose kept) and
   place it in the world; the scale used is in the match details and the report (``scales``). The
   next ``alternatives`` models by score are placed the same way and kept beside it, for the
   physical check to swap to.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from stratamap.core import PipelineData, hookimpl
from stratamap.core.lazy import lazy_module
from stratamap.core.library.index import IndexedModel, ModelIndex, shape_descriptor
from stratamap.core.map.layers import ObjectInstance
from stratamap.core.map.priors import plausible_heights
from stratamap.plugins.completers._matching import Match, MatcherConfig, MatchingCompleter

spatial = lazy_module("scipy.spatial")

#: Joints that open a model's front: a model with one has its doors or drawers where it faces the room.
OPENING_JOINTS = ("revolute", "prismatic")

#: Height scale range for classes without a size prior.
FALLBACK_SCALE_RANGE = (0.85, 1.15)


class ICPMatchConfig(MatcherConfig):
    yaw_samples: int = Field(
        default=36, ge=4, le=360, description="Uniform rotations about z tried in the coarse alignment."
    )
    coarse_translation_steps: int = Field(
        default=6, ge=0, le=30, description="Translation-only ICP steps for each sampled rotation."
    )
    coarse_points: int = Field(
        default=300, ge=20, description="Observed points (evenly spaced) used to rank the coarse rotations."
    )
    icp_iterations: int = Field(
        default=15, ge=1, le=100, description="ICP iterations refining the reference model's pose."
    )
    candidate_iterations: int = Field(
        default=5, ge=0, le=50, description="ICP iterations per candidate from the reference pose."
    )
    max_points: int = Field(
        default=1500, ge=100, description="Observed points used for matching (deterministic subsample)."
    )
    outlier_distance: float = Field(
        default=0.1, gt=0.0, description="Distances are clipped at this in the score, metres (robust to clutter)."
    )
    coverage_weight: float = Field(
        default=1.0, ge=0.0, description="Weight of the coverage term (metres of observation outside the model)."
    )
    scale_range: tuple[float, float] | None = Field(
        default=None,
        description=(
            "Allowed height scale of a model (from the observed height); null: the heights plausible for the class "
            "(core/map/priors.py), else 0.85-1.15."
        ),
    )
    front_tie: float = Field(
        default=0.005,
        ge=0.0,
        description=(
            "Coarse rotations whose mean distance is within this of the best (metres) fit alike (a box seen from one "
            "side fits turned half round as well); when the class's shortlisted models have doors or drawers "
            "(revolute or prismatic joints), the one that turns the model's front (-y, the library's canonical "
            "front) most towards where the object was seen from wins. 0: the best fit alone."
        ),
    )
    footprint_scales: list[float] = Field(
        default_factory=lambda: [0.85, 0.92, 1.0, 1.08, 1.15],
        description=(
            "Width and depth of the best model are each searched over these multiples of its height scale (per axis, "
            "keeping the pose); [1.0] keeps models' proportions."
        ),
    )


def rot2(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def to_model(points: np.ndarray, yaw: float, t: np.ndarray, scale: float) -> np.ndarray:
    """World-relative points (already minus the base) into the unscaled model frame."""
    q = points - np.append(t, 0.0)
    xy = q[:, :2] @ rot2(yaw)  # rotate by -yaw
    return np.c_[xy, q[:, 2]] / scale


def seen_from(points: np.ndarray, views: np.ndarray | None) -> np.ndarray:
    """The mean of the top-view unit directions from the points' centre to the sensor viewpoints: long
    when the object was seen from one side (a cabinet against a wall), short when from all round."""
    if views is None or not len(views):
        return np.zeros(2)
    offsets = np.asarray(views, float)[:, :2] - points[:, :2].mean(axis=0)
    reach = np.linalg.norm(offsets, axis=1)
    offsets = offsets[reach > 1e-6] / reach[reach > 1e-6, None]
    return offsets.mean(axis=0) if len(offsets) else np.zeros(2)


def seen_front_yaw(coarse: np.ndarray, yaws: np.ndarray, towards: np.ndarray, tie: float) -> int:
    """The index of the rotation to refine: of those within ``tie`` of the best coarse fit, the one
    whose model front (-y) points most along ``towards`` (the first best fit when ``towards`` is nil)."""
    best = int(np.argmin(coarse))
    if tie <= 0 or not np.any(towards):
        return best
    tied = np.flatnonzero(coarse <= coarse[best] + tie)
    facing = [float(towards @ (rot2(float(yaws[k])) @ np.array([0.0, -1.0]))) for k in tied]
    return int(tied[int(np.argmax(facing))])


def icp_yaw(
    obs: np.ndarray, model: IndexedModel, yaw: float, t: np.ndarray, scale: float, iterations: int
) -> tuple[float, np.ndarray, np.ndarray]:
    """Yaw and xy translation aligning the model to the observation; returns (yaw, t, distances)."""
    for _ in range(iterations):
        dist, idx = model.tree.query(to_model(obs, yaw, t, scale), workers=1)
        dist = dist * scale
        keep = dist <= max(3.0 * np.median(dist), 0.02)
        if keep.sum() < 10:
            break
        m = model.samples[idx[keep], :2] * scale  # matched model points, model frame
        p = obs[keep, :2]
        mc, pc = m.mean(0), p.mean(0)
        h = (m - mc).T @ (p - pc)
        new_yaw = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
        new_t = pc - rot2(new_yaw) @ mc
        if abs(new_yaw - yaw) < 1e-4 and np.linalg.norm(new_t - t) < 1e-4:
            yaw, t = new_yaw, new_t
            break
        yaw, t = new_yaw, new_t
    dist, _ = model.tree.query(to_model(obs, yaw, t, scale), workers=1)
    return yaw, t, dist * scale


class ICPMatchCompleter(MatchingCompleter[ICPMatchConfig]):
    """Model matching by z-rotation sampling and yaw ICP against a database (augmented-representations paper)."""

    name = "icp_match"
    Config = ICPMatchConfig

    def match(
        self,
        inst: ObjectInstance,
        base: np.ndarray,
        index: ModelIndex,
        data: PipelineData | None,
        views: np.ndarray | None = None,
    ) -> Match | None:
        cfg = self.config
        obs = inst.points - base
        if len(obs) > cfg.max_points:
            obs = obs[np.linspace(0, len(obs) - 1, cfg.max_points).astype(int)]
        local = np.c_[obs[:, :2] @ rot2(inst.box.yaw), obs[:, 2]]
        cands = index.shortlist(inst.class_name, shape_descriptor(local, inst.box.size), cfg.shortlist)
        if not cands:
            return None
        obs_height = float(obs[:, 2].max())
        heights = plausible_heights(inst.class_name)

        def scale_for(m: IndexedModel) -> float:
            model_height = max(float(m.size[2]), 1e-3)
            if cfg.scale_range is not None:
                lo, hi = cfg.scale_range
            elif heights is not None:
                lo, hi = heights[0] / model_height, heights[1] / model_height
            else:
                lo, hi = FALLBACK_SCALE_RANGE
            return float(np.clip(obs_height / model_height, lo, hi))

        ref = index.models[cands[0]]
        s_ref = scale_for(ref)
        yaws = inst.box.yaw + np.arange(cfg.yaw_samples) * (2 * np.pi / cfg.yaw_samples)
        # The coarse search only ranks rotations: an evenly spaced subsample of the points suffices.
        sparse = obs[np.linspace(0, len(obs) - 1, min(len(obs), cfg.coarse_points)).astype(int)]
        coarse, shifts = [], []
        for y in yaws:
            # Translation-only steps per rotation: a partial view's centroid is not the model's.
            t = np.zeros(2)
            for _ in range(cfg.coarse_translation_steps):
                _, idx = ref.tree.query(to_model(sparse, y, t, s_ref), workers=1)
                t = np.mean(sparse[:, :2] - (ref.samples[idx, :2] * s_ref) @ rot2(y).T, axis=0)
            dist = ref.tree.query(to_model(sparse, y, t, s_ref), workers=1)[0] * s_ref
            coarse.append(float(np.mean(np.minimum(dist, cfg.outlier_distance))))
            shifts.append(t)
        # Doors and drawers open into the room the sensor stood in; a model with nothing that opens
        # has no such front (an unseen cup handle more likely faces away from the sensor).
        opens = any(j.type in OPENING_JOINTS for mid in cands for j in index.library.get(mid).joints)
        towards = seen_from(inst.points, views) if opens else np.zeros(2)
        best_yaw = seen_front_yaw(np.asarray(coarse), yaws, towards, cfg.front_tie)
        turned = best_yaw != int(np.argmin(coarse))
        yaw, t, _ = icp_yaw(obs, ref, float(yaws[best_yaw]), shifts[best_yaw], s_ref, cfg.icp_iterations)

        best: Match | None = None
        scored: list[Match] = []
        for mid in cands:
            m = index.models[mid]
            s = scale_for(m)
            y, tt, dist = icp_yaw(obs, m, yaw, t.copy(), s, cfg.candidate_iterations)
            fit = float(np.mean(np.minimum(dist, cfg.outlier_distance)))
            # Coverage: how far the observation reaches beyond the model's extent (model frame).
            q = to_model(obs, y, tt, s) * s
            half = m.size[:2] * s / 2
            out_xy = np.maximum(np.percentile(np.abs(q[:, :2]), 98, axis=0) - half, 0).sum()
            out_z = max(float(np.percentile(q[:, 2], 98)) - m.size[2] * s, 0.0)
            score = fit + cfg.coverage_weight * float(out_xy + out_z)
            candidate = Match(
                mid,
                y,
                base + np.append(tt, 0.0),
                s,
                score,
                {
                    "fit_m": fit,
                    "coverage_m": float(out_xy + out_z),
                    "candidates": len(cands),
                    "front_towards_sensor": int(turned),
                },
            )
            scored.append(candidate)
            if best is None or score < best.score - 1e-12:
                best = candidate
        if best is None:
            return None
        # The next-best models (shortlist order breaks ties), each with its own footprint scale.
        others = sorted((m for m in scored if m is not best), key=lambda m: m.score)[: cfg.alternatives]
        chosen = self.fit_footprint(obs, base, index.models[best.model_id], best)
        chosen.alternatives = [self.fit_footprint(obs, base, index.models[m.model_id], m) for m in others]
        return chosen

    def fit_footprint(self, obs: np.ndarray, base: np.ndarray, m: IndexedModel, best: Match) -> Match:
        """Search width and depth scale per axis around the height scale (pose kept); the scale used
        goes into the match details (``scale``: [x, y, z] along the model's axes)."""
        cfg = self.config
        s = float(best.scale)
        q = to_model(obs, best.yaw, best.translation[:2] - base[:2], 1.0)  # metres, model axes
        chosen, chosen_score = np.array([s, s, s]), None
        factors = sorted(cfg.footprint_scales, key=lambda f: (abs(f - 1.0), f))  # ties keep proportions
        for fx in factors:
            for fy in factors:
                scale = np.array([s * fx, s * fy, s])
                dist = spatial.cKDTree(m.samples * scale).query(q, workers=1)[0]
                fit = float(np.mean(np.minimum(dist, cfg.outlier_distance)))
                half = m.size[:2] * scale[:2] / 2
                out_xy = np.maximum(np.percentile(np.abs(q[:, :2]), 98, axis=0) - half, 0).sum()
                out_z = max(float(np.percentile(q[:, 2], 98)) - m.size[2] * s, 0.0)
                score = fit + cfg.coverage_weight * float(out_xy + out_z)
                if chosen_score is None or score < chosen_score - 1e-4:
                    chosen, chosen_score = scale, score
                    details = {**best.details, "fit_m": fit, "coverage_m": float(out_xy + out_z)}
        details["scale"] = [round(float(v), 4) for v in chosen]
        return Match(best.model_id, best.yaw, best.translation, chosen, float(chosen_score), details)

    def complete(self, data: PipelineData) -> dict:
        out = super().complete(data)
        # Which completions the sensor's side turned (front_tie): a user checking a door that opens
        # the wrong way starts here.
        self.note(
            "fronts_towards_sensor",
            [
                inst.id
                for inst in out["instances"]
                if inst.completion is not None
                and inst.completion.completer == self.name
                and inst.attributes.get("match", {}).get("front_towards_sensor")
            ],
        )
        self.note(
            "scales",
            {
                str(inst.id): [round(float(v), 3) for v in inst.completion.scale]
                for inst in out["instances"]
                if inst.completion is not None and inst.completion.completer == self.name
            },
        )
        return out


@hookimpl
def stratamap_register_completers():
    return [ICPMatchCompleter]
