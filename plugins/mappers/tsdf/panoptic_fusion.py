"""Panoptic fusion into a TSDF, after Voxblox++ (Grinvald et al. 2019) as extended by the
functional-scenes paper (Han et al. 2021, section 3).

State, kept inside the TSDF's own voxel blocks (extra attributes ``label`` and ``conf``):

* every voxel holds a *segment label* lab and a confidence count;
* every label lab holds a count Phi(lab, c, p) of how often it was observed as semantic class c of
  global instance p.

Per frame:

1. The segmenter's per-pixel (class, instance) pairs define the frame's segments s.
2. Association: pixels of s fall in voxels; the overlap Pi(s, lab) counts those carrying label lab.
   Pairs are assigned greedily by decreasing overlap score max(Pi / |s|, Pi / |lab in view|) (each
   s and lab at most once per frame) when it reaches ``associate_ratio``, except across a stuff
   class (floor, wall, ceiling: layout never changes class); an unassigned segment starts a new label.
3. Label merging: when a segment also covers most of another label's voxels in view
   (shared-voxel ratio >= ``merge_ratio``) in ``merge_votes`` frames, the two labels merge
   (only when that label stands for the segment's class, or for none yet).
4. Voxels take the segment's label (Voxblox++'s confidence rule: agree +1, disagree -1, replace at 0).
5. Instances: a thing segment's global instance is the one the labels it overlaps stand for,
   weighted by overlap (each label stands for argmax_p sum_c Phi(lab, c, p)), unless another segment
   of the frame claimed it first; else a new one. Then Phi(lab, c_s, p_s) += 1.
6. Instance merging (eq. 5): two instances merge when one label's votes are split between them,
   each holding at least ``instance_merge_ratio`` of that label's votes.
7. Extraction (eq. 6): every label takes (c*, p*) = argmax Phi(lab, c, p); voxels, hence map points,
   take their label's class and instance; stuff classes get instance 0.

The ``tsdf`` mapper's default (``instances: masks``) builds the map's instances from these labels
differently, robust to a segmenter's merged masks: see :mod:`stratamap.plugins.mappers.tsdf.mask_instances`.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from stratamap.core.map.vocabulary import Vocabulary

SEGMENT_SHIFT = np.int64(1) << 32


@dataclass
class PanopticParams:
    associate_ratio: float = 0.2
    merge_ratio: float = 0.5
    merge_votes: int = 2
    instance_merge_ratio: float = 0.3
    min_label_voxels: int = 4


@dataclass
class PanopticState:
    """The label-level statistics (the voxel labels live in the TSDF blocks)."""

    params: PanopticParams
    vocabulary: Vocabulary
    phi: dict[int, Counter] = field(default_factory=lambda: defaultdict(Counter))  # label -> Counter[(class, instance)]
    merge_votes: Counter = field(default_factory=Counter)  # (keep, drop) -> frames
    merged_into: dict[int, int] = field(default_factory=dict)
    seen_apart: set = field(default_factory=set)  # instance pairs segmented as two objects in one frame
    next_label: int = 1
    next_instance: int = 1
    voxels_per_block: int = 512
    #: The label each label stands for now (itself until merged): voxels keep the label they were
    #: given and are read through this table, so a merge costs a pass over the labels, not over
    #: every voxel of the map (which made merges slower the larger the map).
    canonical: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))

    def new_label(self) -> int:
        label = self.next_label
        self.next_label += 1
        if label >= len(self.canonical):
            self.canonical = np.append(self.canonical, np.arange(len(self.canonical), 2 * len(self.canonical) + 1))
        return label

    def current(self, voxel_labels: np.ndarray) -> np.ndarray:
        """What labels stand for now (merges applied), as int64."""
        labels = np.asarray(voxel_labels, np.int64)
        if len(self.canonical) < self.next_label:  # labels set from outside (tests): none merged yet
            self.canonical = np.append(self.canonical, np.arange(len(self.canonical), self.next_label))
        inside = labels < len(self.canonical)
        return np.where(inside, self.canonical[np.where(inside, labels, 0)], labels)

    def resolve(self, label: int) -> int:
        while label in self.merged_into:
            label = self.merged_into[label]
        return label

    # ---------------------------------------------------------------- per frame

    def fuse_frame(
        self,
        voxel_labels: np.ndarray,
        voxel_conf: np.ndarray,
        flat: np.ndarray,
        seg_class: np.ndarray,
        seg_instance: np.ndarray,
    ) -> None:
        """Fuse one frame. ``flat`` are the voxel indices of the frame's sampled pixels (one per voxel),
        ``seg_class``/``seg_instance`` the segmenter's labels of those pixels; ``voxel_labels`` and
        ``voxel_conf`` are writable views of the TSDF's label attributes, shaped (blocks, voxels per
        block) or flat. Merges rewrite no voxel (see ``canonical``)."""
        if len(flat) == 0:
            return
        p = self.params
        code = (seg_class.astype(np.int64) << 32) | seg_instance.astype(np.int64)
        seg_codes, seg_of_point = np.unique(code, return_inverse=True)
        seg_sizes = np.bincount(seg_of_point)
        stored = voxel_labels[flat]  # merges below change what labels stand for, never the stored labels
        current = self.current(stored)
        # label_class walks a label's Phi; a frame asks it of the same labels again and again, and only
        # a merge changes the answers.
        class_of: dict[int, int] = {}

        def label_class(label: int) -> int:
            if label not in class_of:
                class_of[label] = self.label_class(label)
            return class_of[label]

        # Overlap Pi(s, l) of frame segments with existing labels.
        has = current > 0
        pair = seg_of_point[has].astype(np.int64) * SEGMENT_SHIFT + current[has]
        pairs, counts = np.unique(pair, return_counts=True)
        pair_seg = (pairs // SEGMENT_SHIFT).astype(np.int64)
        pair_label = (pairs % SEGMENT_SHIFT).astype(np.int64)
        visible = (
            Counter(dict(zip(*np.unique(current[has], return_counts=True), strict=True))) if has.any() else Counter()
        )

        # Overlap normalised both ways: a big object's new view may mostly cover unseen voxels
        # (small Pi/|s|) while still covering most of the label's voxels in view (large Pi/|l|).
        vis = np.array([visible[int(lab)] for lab in pair_label], dtype=np.float64)
        score = np.maximum(counts / seg_sizes[pair_seg], counts / np.maximum(vis, 1))
        assigned: dict[int, int] = {}
        used_labels: set[int] = set()
        is_thing = self.vocabulary.is_thing
        for idx in np.lexsort((-counts, -score)):
            s, lab, n = int(pair_seg[idx]), int(pair_label[idx]), int(counts[idx])
            if s in assigned or lab in used_labels or score[idx] < p.associate_ratio or n < 3:
                continue
            # Layout (stuff) segments and labels pair only with their own class: a wall's label
            # must not become the floor's because a segmenter calls the foot of the wall floor.
            c_seg, c_label = int(seg_codes[s] >> 32), label_class(lab)
            if c_label and c_seg and c_seg != c_label and not (is_thing[c_seg] and is_thing[c_label]):
                continue
            assigned[s] = lab
            used_labels.add(lab)
        # Shared-voxel ratio: a segment covering most of another label's visible voxels votes to
        # merge them, if that label stands for the segment's class (a floor segment spilling over
        # the foot of a wall whose label is mostly out of view must not swallow the wall).
        merged = False
        for idx in range(len(pairs)):
            s, lab = int(pair_seg[idx]), int(pair_label[idx])
            keep = assigned.get(s)
            if keep is None or keep == lab:
                continue
            other = label_class(lab)
            if other not in (0, int(seg_codes[s] >> 32)):
                continue
            if counts[idx] >= p.merge_ratio * visible[lab] and counts[idx] >= 3:
                key = (keep, lab)
                self.merge_votes[key] += 1
                if self.merge_votes[key] >= p.merge_votes:
                    self._merge_labels(keep, lab, voxel_labels)
                    class_of.clear()
                    merged = True
        for s in range(len(seg_codes)):
            if s not in assigned:
                assigned[s] = self.new_label()

        # Voxel label update with Voxblox++'s confidence counts.
        new = np.array([assigned[s] for s in range(len(seg_codes))], dtype=np.int64)[seg_of_point]
        cur = self.current(stored) if merged else current
        conf = voxel_conf[flat]
        agree = cur == new
        conf = np.where(agree, conf + 1, conf - 1)
        replace = conf <= 0
        cur = np.where(replace, new, cur)
        conf = np.where(replace, 1, np.minimum(conf, 1000))
        voxel_labels[flat] = cur.astype(voxel_labels.dtype)
        voxel_conf[flat] = conf.astype(voxel_conf.dtype)

        # Instance association: a mask's instance is the one the labels it overlaps vote for,
        # weighted by overlap (Voxblox++); then the count Phi(l, c, p).
        # Only labels standing for the segment's class vote: a table segment reaching over a
        # chair's voxels must not take the chair's instance (a segmenter's noisy class borders
        # would otherwise chain neighbouring objects of different classes into one instance).
        label_best: dict[int, tuple[int, int]] = {}
        for lab in set(pair_label.tolist()):
            label_best[lab] = (label_class(lab), self.best_instance(lab))
        seg_votes: dict[int, Counter] = defaultdict(Counter)
        for idx in range(len(pairs)):
            c_label, best = label_best[int(pair_label[idx])]
            if best > 0 and c_label == int(seg_codes[int(pair_seg[idx])] >> 32):
                seg_votes[int(pair_seg[idx])][best] += int(counts[idx])
        claimed: set[int] = set()
        for s in np.argsort(-seg_sizes, kind="stable"):
            s = int(s)
            c = int(seg_codes[s] >> 32)
            inst_2d = int(seg_codes[s] & 0xFFFFFFFF)
            label = self.resolve(assigned[s])
            if c == 0:
                continue
            if not self.vocabulary.is_thing[c] or inst_2d == 0:
                self.phi[label][(c, 0)] += 1
                continue
            votes = seg_votes.get(s, Counter())
            if not votes:
                votes = Counter({pp: n for (cc, pp), n in self.phi[label].items() if pp > 0 and cc == c})
            inst = next((pp for pp, _ in votes.most_common() if pp not in claimed), None)
            if inst is None:
                inst = self.next_instance
                self.next_instance += 1
            claimed.add(inst)
            self.phi[label][(c, inst)] += 1
        self.seen_apart.update(combinations(sorted(claimed), 2))

    def label_class(self, label: int) -> int:
        """The class a label stands for so far (most votes in Phi; 0 before any)."""
        votes: Counter = Counter()
        for (c, _), n in self.phi.get(self.resolve(label), Counter()).items():
            votes[c] += n
        return int(votes.most_common(1)[0][0]) if votes else 0

    def best_instance(self, label: int) -> int:
        by_inst: Counter = Counter()
        for (_, pp), n in self.phi.get(self.resolve(label), Counter()).items():
            if pp > 0:
                by_inst[pp] += n
        return by_inst.most_common(1)[0][0] if by_inst else 0

    def _merge_labels(self, keep: int, drop: int, voxel_labels: np.ndarray) -> None:
        keep, drop = self.resolve(keep), self.resolve(drop)
        if keep == drop:
            return
        self.canonical[self.canonical == drop] = keep
        self.phi[keep].update(self.phi.pop(drop, Counter()))
        self.merged_into[drop] = keep

    # ---------------------------------------------------------------- instance merging and extraction

    def merge_instances(self) -> dict[int, int]:
        """Eq. 5: merge instances whose votes share a label (each holding enough of its votes)."""
        parent: dict[int, int] = {}

        def find(x: int) -> int:
            while parent.get(x, x) != x:
                x = parent[x]
            return x

        for counter in self.phi.values():
            # Per class: a label seen as a chair of one instance and a table of another links
            # nothing (the class votes disagree, not the instances).
            by_class: dict[int, Counter] = defaultdict(Counter)
            for (c, pp), n in counter.items():
                if pp > 0:
                    by_class[c][pp] += n
            total = sum(sum(v.values()) for v in by_class.values())
            for by_inst in by_class.values():
                strong = [pp for pp, n in by_inst.items() if n >= self.params.instance_merge_ratio * total]
                for other in strong[1:]:
                    a, b = find(strong[0]), find(other)
                    if a != b:
                        parent[max(a, b)] = min(a, b)
        mapping = {x: find(x) for x in list(parent)}
        if mapping:
            for label, counter in self.phi.items():
                merged: Counter = Counter()
                for (c, pp), n in counter.items():
                    merged[(c, mapping.get(pp, pp))] += n
                self.phi[label] = merged
        return mapping

    def merge_fragments(
        self, point_class: np.ndarray, point_instance: np.ndarray, points: np.ndarray, touch: float
    ) -> dict[int, int]:
        """Merge same-class instances whose points touch (within ``touch`` metres) and that no frame
        ever segmented as two objects: the pieces of an object first seen from views that did not
        overlap. Returns the mapping applied to ``point_instance`` (in place)."""
        from scipy.spatial import cKDTree

        ids = [int(i) for i in np.unique(point_instance) if i > 0]
        if len(ids) < 2:
            return {}
        # Points grouped by instance once (a mask per instance would scan every point per instance).
        order = np.argsort(point_instance, kind="stable")
        uniq, starts = np.unique(point_instance[order], return_index=True)
        bounds = dict(
            zip(uniq.tolist(), zip(starts.tolist(), [*starts[1:].tolist(), len(order)], strict=True), strict=True)
        )
        members_of = {i: order[bounds[i][0] : bounds[i][1]] for i in ids}
        cls = {i: int(np.bincount(point_class[members_of[i]]).argmax()) for i in ids}
        trees = {i: cKDTree(points[members_of[i]]) for i in ids}
        lo = np.array([trees[i].mins - touch for i in ids])
        hi = np.array([trees[i].maxes + touch for i in ids])
        parent = {i: i for i in ids}
        members = {i: [i] for i in ids}  # per root: the instances merged into it
        apart_from = {i: set() for i in ids}  # per root: instances some member was segmented apart from
        for a, b in self.seen_apart:
            if a in apart_from and b in apart_from:
                apart_from[a].add(b)
                apart_from[b].add(a)

        def find(x: int) -> int:
            while parent[x] != x:
                x = parent[x]
            return x

        # Candidate pairs: boxes (grown by ``touch``) that overlap, by a sweep along x, in the
        # order the all-pairs loop took them (merges depend on the order).
        by_x = np.argsort(lo[:, 0], kind="stable")
        candidates = []
        for pos, a_idx in enumerate(by_x):
            for b_idx in by_x[pos + 1 :]:
                if lo[b_idx, 0] > hi[a_idx, 0]:
                    break
                if np.all(lo[a_idx] <= hi[b_idx]) and np.all(lo[b_idx] <= hi[a_idx]):
                    candidates.append((min(a_idx, b_idx), max(a_idx, b_idx)))
        for a_idx, b_idx in sorted(candidates):
            a, b = ids[a_idx], ids[b_idx]
            if cls[a] != cls[b]:
                continue
            ra, rb = find(a), find(b)
            if ra == rb or any(m in apart_from[ra] for m in members[rb]):
                continue
            if trees[a].sparse_distance_matrix(trees[b], touch, output_type="ndarray").size == 0:
                continue
            keep, drop = min(ra, rb), max(ra, rb)
            parent[drop] = keep
            members[keep] += members.pop(drop)
            apart_from[keep] |= apart_from.pop(drop)
        mapping = {i: find(i) for i in ids if find(i) != i}
        if mapping:
            lookup = np.arange(int(point_instance.max()) + 1, dtype=point_instance.dtype)
            for old, new in mapping.items():
                lookup[old] = new
            positive = point_instance > 0
            point_instance[positive] = lookup[point_instance[positive]]
        return mapping

    def label_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 6: per label id, its class c* and instance p* (arrays indexed by label)."""
        size = self.next_label
        classes = np.zeros(size, np.int32)
        instances = np.zeros(size, np.int32)
        for label, counter in self.phi.items():
            if not counter or label >= size:
                continue
            (c, pp), _ = max(counter.items(), key=lambda kv: (kv[1], -kv[0][0], -kv[0][1]))
            classes[label] = c
            instances[label] = pp if self.vocabulary.is_thing[c] else 0
        for drop, keep in self.merged_into.items():
            k = self.resolve(keep)
            if drop < size and k < size:
                classes[drop], instances[drop] = classes[k], instances[k]
        return classes, instances
