"""Completer ``plane_box_match``: CAD matching with boxes, planes and physical reasoning
(functional-scenes paper, sections 4.2-4.4).

Per object:

1. Observed box (gravity-aligned, extended down to the supporting plane) and observed planes
   (iterative RANSAC on the object's points, horizontal and vertical ones kept).
2. Matching error over the 24 canonical orientations of each shortlisted model (6 up axes x 4
   quarter turns): ME = d_s + d_pi + 0.2 d_b, where d_s is the relative box-size difference
   (eq. 8), d_pi the plane misalignment under the optimal assignment of model planes to observed
   planes by the Hungarian method (eq. 9), d_b the upright bias (eq. 10, 0 when the model's up
   stays up). The ``keep`` best (model, orientation) pairs go on.
3. Alignment by Levenberg-Marquardt over yaw, uniform scale and horizontal translation (the
   object rests on its supporting plane) on box residuals (eq. 12-13: the aligned model box
   against the observed box) and plane residuals (eq. 14: observed plane inliers against their
   assigned model planes). Alignment error AE = RMS distance from the object's points to the
   aligned model surface.

Globally (section 4.4): every candidate is posed resting on its supporting plane; candidates that
disagree with the observed points (see ``rejection_reason``), penetrate the layout (floor, ceiling,
wall points inside the model), would not stay as posed (they rock onto another face of their hull:
a cup on its round side; not in the paper, whose scenes were not simulated) or cannot support their
children (support area ratio below b_th, eq. 2) are discarded; the min-conflict algorithm then
chooses one candidate per object so that no two chosen models' meshes interpenetrate, trying every
conflicted object's candidates and preferring low AE, independently of object ids
(``core/simulation/physics.py``'s :func:`min_conflict`). The candidates left beside the chosen one
are kept on its completion (``alternatives``, best first) for the physical check.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import PipelineData, hookimpl
from stratamap.core.geometry.points import ransac_plane
from stratamap.core.lazy import lazy_module
from stratamap.core.library.index import IndexedModel, ModelIndex, shape_descriptor
from stratamap.core.map.layers import Completion, ObjectInstance, OrientedBox
from stratamap.core.simulation.physics import Placement, Shell, conflicted, mesh_shells, min_conflict
from stratamap.core.simulation.rest import rocking_angle
from stratamap.plugins.completers._matching import (
    Match,
    MatcherConfig,
    MatchingCompleter,
    load_index,
    object_base,
    posed_completion,
    rejection_reason,
)

optimize = lazy_module("scipy.optimize")


def canonical_orientations() -> list[np.ndarray]:
    """The 24 rotations of the cube group, upright ones first."""
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            r = np.zeros((3, 3))
            for i, (p, s) in enumerate(zip(perm, signs, strict=True)):
                r[i, p] = s
            if np.isclose(np.linalg.det(r), 1.0):
                mats.append(r)
    mats.sort(key=lambda r: (-r[2, 2], tuple(np.round(r.reshape(-1), 3))))
    return mats


ORIENTATIONS = canonical_orientations()


@dataclass
class Candidate:
    model_id: str
    orientation: int
    me: float
    yaw: float = 0.0
    scale: float = 1.0
    translation: np.ndarray | None = None
    ae: float = np.inf
    size: np.ndarray | None = None  # aligned model box size (in the object's yaw frame)
    completion: Completion | None = None  # the posed model, once the global step poses it
    shells: list[Shell] | None = None  # its convex pieces, world frame
    layout_depth: float = 0.0  # how deep it reaches through floor, walls or ceiling beyond tolerance
    rocking: float = 0.0  # degrees it rocks, set down as posed, before it rests on a face (0: at rest)


class PlaneBoxConfig(MatcherConfig):
    keep: int = Field(
        default=10, ge=1, le=50, description="Oriented candidates kept after the matching error (the paper keeps 10)."
    )
    upright_weight: float = Field(
        default=0.2, ge=0.0, description="Weight of the upright bias d_b in the matching error (eq. 10)."
    )
    plane_distance: float = Field(
        default=0.015, gt=0.0, description="RANSAC inlier distance of observed planes, metres."
    )
    max_planes: int = Field(default=4, ge=0, le=8, description="Planes extracted per object.")
    support_ratio: float = Field(
        default=0.5,
        gt=0.0,
        le=1.0,
        description="b_th: share of a child's footprint its parent's top must support (eq. 2).",
    )
    penetration_tolerance: float = Field(
        default=0.02,
        ge=0.0,
        description="Tolerated overlap depth between models and of models below the floor, metres.",
    )
    min_conflict_iterations: int = Field(default=200, ge=1, description="Iterations of the min-conflict search.")
    max_rocking_deg: float = Field(
        default=5.0,
        ge=0.0,
        description=(
            "Candidates that would rock further than this, set down as posed, before resting on a face (a cup on "
            "its round side: about 9 degrees) are dropped unless every candidate would, degrees."
        ),
    )


def observed_planes(points: np.ndarray, cfg: PlaneBoxConfig) -> list[tuple[np.ndarray, float, np.ndarray]]:
    planes, rest = [], points
    for k in range(cfg.max_planes):
        if len(rest) < 60:
            break
        n, d, inl = ransac_plane(rest, cfg.plane_distance, iterations=200, seed=k)
        if len(inl) < max(40, 0.08 * len(points)):
            break
        if abs(n[2]) > 0.9 or abs(n[2]) < 0.15:  # horizontal or vertical
            planes.append((n, d, rest[inl]))
        rest = np.delete(rest, inl, axis=0)
    return planes


def model_planes(m: IndexedModel, rot: np.ndarray) -> list[tuple[np.ndarray, float, float]]:
    """Feature planes of a model under a canonical rotation (normal, offset, area), centered box frame."""
    out = []
    center = np.array([0.0, 0.0, m.size[2] / 2])
    for nx, ny, nz, d, area in m.planes[:8]:
        n = np.array([nx, ny, nz])
        point = -d * n - center  # a point on the plane, relative to the box center
        rn = rot @ n
        out.append((rn, -float(rn @ (rot @ point)), float(area)))
    return out


class PlaneBoxMatchCompleter(MatchingCompleter[PlaneBoxConfig]):
    """CAD matching over 24 orientations with box/plane errors, Hungarian plane assignment, LM alignment and min-conflict physics."""  # noqa: E501 (one-line summary shown by `stratamap plugins`)

    name = "plane_box_match"
    Config = PlaneBoxConfig

    # ---------------------------------------------------------------- per object

    def candidates(
        self, inst: ObjectInstance, base: np.ndarray, index: ModelIndex
    ) -> tuple[list[Candidate], dict[str, Any]]:
        cfg = self.config
        pts = inst.points
        yaw0 = inst.box.yaw
        c, s = np.cos(yaw0), np.sin(yaw0)
        local = pts - base
        local = np.c_[local[:, :2] @ np.array([[c, -s], [s, c]]), local[:, 2]]
        # Observed box, extended down to the supporting plane (the paper's refined box).
        lo = np.r_[np.percentile(local[:, :2], 1, axis=0), 0.0]
        hi = np.percentile(local, 99, axis=0)
        obs_size = np.maximum(hi - lo, 0.02)
        obs_center = (hi + lo) / 2
        planes = observed_planes(local - obs_center, cfg)
        cands = index.shortlist(inst.class_name, shape_descriptor(local, obs_size), cfg.shortlist)
        scored: list[Candidate] = []
        for mid in cands:
            m = index.models[mid]
            for oi, rot in enumerate(ORIENTATIONS):
                size = np.abs(rot) @ m.size
                # Scale from the height: the observation is partial sideways, rarely in height.
                sc = obs_size[2] / max(size[2], 1e-3)
                size = size * sc
                d_s = float(np.sum(np.abs(obs_size - size) / np.maximum(obs_size, 1e-3)))
                d_pi = self._plane_error(planes, model_planes(m, rot), sc)
                d_b = 0.0 if rot[2, 2] > 0.5 else 1.0
                scored.append(Candidate(mid, oi, d_s + d_pi + cfg.upright_weight * d_b))
        scored.sort(key=lambda cnd: (cnd.me, cnd.model_id, cnd.orientation))
        top = scored[: cfg.keep]
        for cnd in top:
            self._align(cnd, index.models[cnd.model_id], local, obs_size, obs_center, planes, yaw0, base)
        top.sort(key=lambda cnd: (cnd.ae, cnd.me))
        return top, {"observed_planes": len(planes), "observed_box": obs_size.tolist()}

    @staticmethod
    def _plane_error(obs: list, model: list, scale: float) -> float:
        """d_pi: optimal assignment (Hungarian) of model planes to observed planes."""
        if not obs:
            return 0.0
        if not model:
            return float(len(obs))
        cost = np.zeros((len(obs), len(model)))
        for i, (n_o, d_o, _) in enumerate(obs):
            for j, (n_m, d_m, _) in enumerate(model):
                angle = 1.0 - float(np.dot(n_o, n_m))
                offset = abs(d_o - d_m * scale)
                cost[i, j] = angle + offset
        rows, cols = optimize.linear_sum_assignment(cost)
        unmatched = len(obs) - len(rows)
        return float(cost[rows, cols].sum() + unmatched) / len(obs)

    def _align(
        self,
        cnd: Candidate,
        m: IndexedModel,
        local: np.ndarray,
        obs_size: np.ndarray,
        obs_center: np.ndarray,
        planes: list,
        yaw0: float,
        base: np.ndarray,
    ) -> None:
        """Levenberg-Marquardt on box and plane residuals over (yaw, log scale, tx, ty)."""
        rot = ORIENTATIONS[cnd.orientation]
        samples = (rot @ m.samples.T).T
        # Orientation-rotated model standing on z = 0, centered on its box.
        lo_m = samples.min(0)
        hi_m = samples.max(0)
        samples = samples - np.array([(lo_m[0] + hi_m[0]) / 2, (lo_m[1] + hi_m[1]) / 2, lo_m[2]])
        size0 = hi_m - lo_m
        s0 = obs_size[2] / max(size0[2], 1e-3)
        # Plane inliers (a few per plane) give point-to-surface residuals (eq. 14).
        anchors = (
            np.vstack([p[2][:: max(1, len(p[2]) // 40)] + obs_center for p in planes])
            if planes
            else local[:: max(1, len(local) // 80)]
        )
        from scipy.spatial import cKDTree

        tree = cKDTree(samples)

        def transform(x: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
            yaw, log_s, tx, ty = x
            return (
                np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]),
                float(np.exp(log_s)),
                np.array([tx, ty]),
            )

        def residuals(x: np.ndarray) -> np.ndarray:
            r2, s, t = transform(x)
            size = s * size0
            # Box residuals: the aligned model box against the observed box (extent and center).
            ext = np.abs(r2) @ size[:2]
            box_res = np.r_[
                (ext - obs_size[:2]) / np.maximum(obs_size[:2], 0.05) * 0.2,
                (size[2] - obs_size[2]) / max(obs_size[2], 0.05),
                (t - obs_center[:2]) * 2.0,
            ]
            q = anchors.copy()
            q[:, :2] = (q[:, :2] - t) @ r2  # into the model's frame
            d, _ = tree.query(q / s)
            return np.r_[box_res, np.minimum(d * s, 0.1) * 4.0]

        # The quarter turns are among the 24 orientations already: one start at yaw 0 suffices.
        x0 = np.array([0.0, np.log(s0), obs_center[0], obs_center[1]])
        best = optimize.least_squares(residuals, x0, method="lm", max_nfev=40)
        r2, s, t = transform(best.x)
        q = local.copy()
        q[:, :2] = (q[:, :2] - t) @ r2
        d, _ = tree.query(q / s)
        cnd.ae = float(np.sqrt(np.mean(np.minimum(d * s, 0.2) ** 2)))
        cnd.scale = s
        cnd.yaw = float(yaw0 + best.x[0])
        c0, s0_ = np.cos(yaw0), np.sin(yaw0)
        world_t = np.array([[c0, -s0_], [s0_, c0]]) @ t
        cnd.translation = base + np.r_[world_t, 0.0]
        cnd.size = s * size0
        offset = np.array([(lo_m[0] + hi_m[0]) / 2, (lo_m[1] + hi_m[1]) / 2, lo_m[2]])
        cnd.samples_offset = offset  # type: ignore[attr-defined]

    # ---------------------------------------------------------------- global physical reasoning

    def complete(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        index = load_index(cfg)
        insts = data.map.instances.copy()  # type: ignore[union-attr]
        todo = self.select(insts, index)
        results = self.map_objects(todo, "candidates", index, data)
        layout = Layout.from_map(data)
        options: dict[int, list[Candidate]] = {}
        for inst, (cands, info) in results:
            inst.attributes["match"] = info
            support_z = float(object_base(inst, data)[2])
            seen_ok, reasons = [], []
            for cnd in cands:
                cnd.completion = self._posed(cnd, index, support_z)
                reason = rejection_reason(inst, cnd.completion, cfg)
                if reason is not None:
                    reasons.append(reason)
                    continue
                cnd.shells = mesh_shells(cnd.completion.world_mesh())
                cnd.layout_depth = layout.penetration(cnd.shells, cfg.penetration_tolerance)
                cnd.rocking = rocking_angle(cnd.completion.world_mesh())
                seen_ok.append(cnd)
            if not seen_ok:
                self.reject(inst, reasons[0] if reasons else "no candidate")
                continue
            # Layout (floor, walls, ceiling): candidates that penetrate it go, unless all do.
            inside = [c for c in seen_ok if c.layout_depth <= 0.0] or sorted(seen_ok, key=lambda c: c.layout_depth)[:1]
            # Candidates that would not stay as posed (a cup on its round side rocks onto a facet)
            # go, unless all would: the scene is to rest as completed.
            options[inst.id] = [c for c in inside if c.rocking <= cfg.max_rocking_deg] or inside
        self._support_check(options, data, cfg)
        placements = {i: [placement(c) for c in cands] for i, cands in options.items()}
        choice = min_conflict(placements, cfg.penetration_tolerance, cfg.min_conflict_iterations)
        left = conflicted(choice, cfg.penetration_tolerance)
        if left:
            self.warn(f"completed models still interpenetrating after the min-conflict search: {left}")
        for inst, _ in results:
            if inst.id not in choice:
                continue
            cnd: Candidate = choice[inst.id].item
            inst.completion = cnd.completion
            # The other candidates that passed every check, best first: the physical check may swap to one.
            others = [c for c in options[inst.id] if c is not cnd][: cfg.alternatives]
            inst.completion.alternatives = [c.completion for c in others]  # type: ignore[union-attr,misc]
            inst.attributes["match"].update({"me": cnd.me, "ae": cnd.ae, "layout_penetration_m": cnd.layout_depth})
        return self.finish(insts, data, len(todo))

    def _posed(self, cnd: Candidate, index: ModelIndex, support_z: float) -> Completion:
        """The candidate's model scaled, oriented and resting on its support at ``support_z``."""
        translation = cnd.translation.copy()  # type: ignore[union-attr]
        translation[2] = support_z
        model = index.library.get(cnd.model_id)
        rot = ORIENTATIONS[cnd.orientation]
        upright = bool(np.isclose(rot[2, 2], 1.0))
        # An upright orientation is a quarter turn about z: it belongs in the pose's yaw.
        yaw = cnd.yaw + (float(np.arctan2(rot[1, 0], rot[0, 0])) if upright else 0.0)
        match = Match(
            cnd.model_id,
            yaw,
            translation,
            cnd.scale,
            cnd.ae,
            {"me": cnd.me, "ae": cnd.ae, "orientation": cnd.orientation},
        )
        completion = posed_completion(model, match, self.name)
        if not upright:
            orient = np.eye(4)
            orient[:3, :3] = rot
            completion.mesh.apply_transform(orient)
            lo, hi = completion.mesh.bounds
            completion.mesh.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
            completion.pose[2, 3] = support_z  # the re-oriented model's bottom is its frame's origin again
            completion.parts, completion.joints = [], []  # articulation is defined for the upright model only
        return completion

    @staticmethod
    def _footprint(c: Candidate) -> OrientedBox:
        assert c.translation is not None and c.size is not None
        return OrientedBox(c.translation + np.array([0, 0, c.size[2] / 2]), c.yaw, c.size)

    def _support_check(self, options: dict[int, list[Candidate]], data: PipelineData, cfg: PlaneBoxConfig) -> None:
        """Eq. 2: a parent candidate must give each supported child at least b_th of its footprint."""
        from stratamap.core.geometry.boxes import footprint_overlap

        graph = data.map.contact_graph
        insts = data.map.instances
        if graph is None or insts is None:
            return
        for pid, cands in options.items():
            children = [c for c in graph.support.successors(pid) if isinstance(c, int) and c in insts]
            if not children:
                continue
            kept = []
            for cand in cands:
                box = self._footprint(cand)
                ok = all(
                    footprint_overlap(insts[ch].box, box)
                    >= cfg.support_ratio * max(insts[ch].box.size[0] * insts[ch].box.size[1], 1e-6)
                    for ch in children
                )
                if ok:
                    kept.append(cand)
            options[pid] = kept or cands[:1]


@dataclass
class Layout:
    """The room's layout as the map saw it: floor and ceiling heights and the wall points."""

    floor_z: float = 0.0
    ceiling_z: float | None = None
    walls: np.ndarray | None = None  # (N, 3) wall points

    @classmethod
    def from_map(cls, data: PipelineData) -> Layout:
        sem, geom = data.map.semantics, data.map.geometry
        out = cls(float(data.notes.get("occupancy", {}).get("floor_z", 0.0)))
        if sem is None or geom is None or len(sem) != len(geom):
            return out
        for name in ("floor", "ceiling", "wall"):
            if name not in sem.vocabulary:
                continue
            pts = geom.points[sem.class_ids == sem.vocabulary.id(name)]
            if len(pts) < 100:
                continue
            if name == "floor":
                out.floor_z = float(np.median(pts[:, 2]))
            elif name == "ceiling":
                out.ceiling_z = float(np.median(pts[:, 2]))
            else:
                out.walls = pts
        return out

    def penetration(self, shells: list[Shell], tolerance: float) -> float:
        """How deep (m) a model's shells reach through the floor, the ceiling or the walls beyond ``tolerance``."""
        if not shells:
            return 0.0
        lo = np.min([s.lo for s in shells], axis=0)
        hi = np.max([s.hi for s in shells], axis=0)
        depth = max(self.floor_z - lo[2], 0.0)
        if self.ceiling_z is not None:
            depth = max(depth, hi[2] - self.ceiling_z)
        if self.walls is not None:
            near = self.walls[np.all((self.walls >= lo - tolerance) & (self.walls <= hi + tolerance), axis=1)]
            for s in shells if len(near) else []:
                depth = max(depth, float(s.depth(near).max(initial=0.0)))
        return max(depth - tolerance, 0.0)


def placement(cnd: Candidate) -> Placement:
    """A candidate for the min-conflict search: shells, alignment error, ties broken by model and orientation."""
    return Placement(cnd.shells or [], cnd.ae, (cnd.model_id, cnd.orientation), cnd)


@hookimpl
def stratamap_register_completers():
    return [PlaneBoxMatchCompleter]
