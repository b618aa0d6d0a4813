"""From the raw outputs of exported segmentation networks to per-pixel class and instance images.

Three output layouts, the ones people actually export:

* ``maskrcnn``: boxes (N, 4) x1 y1 x2 y2, labels (N,), scores (N,), masks (N, 1, h, w), either
  full-image masks or box-relative ones (28 x 28 in the ONNX model zoo's Mask R-CNN) that are
  resized into their box;
* ``yolo_seg`` (YOLOv8 / YOLO11-seg): detections (1, 4 + classes + k, anchors) with boxes as
  center x, center y, width, height, per-class scores and k mask coefficients, plus prototypes
  (1, k, mh, mw); masks are sigmoid(coefficients . prototypes) cropped to their box, after
  class-aware non-maximum suppression;
* ``semantic_boundary`` (stratamap's own model): class logits (1, C, H, W) and instance-boundary
  logits (1, 1, H, W); instances are the connected regions of each thing class once boundary
  pixels are removed, boundary pixels then join the nearest region of their class. Optional
  clean-ups: class specks take the class around them, class regions the network is unsure of are
  left unknown, and with depth, instances meeting at a depth-continuous seam merge.

Every adapter returns ``(class_ids, instance_ids, scores)`` at the network's input resolution,
with class ids already mapped to the map's vocabulary (unmapped classes become 0, unknown).
"""

from __future__ import annotations

import numpy as np

from stratamap.core.lazy import lazy_module

ndimage = lazy_module("scipy.ndimage")
sparse = lazy_module("scipy.sparse")
csgraph = lazy_module("scipy.sparse.csgraph")


def _paste(class_ids, instance_ids, scores, masks, labels, confidences) -> None:
    """Draw instance masks lowest score first, so the most confident one wins overlaps."""
    for k in np.argsort(confidences, kind="stable"):
        m = masks[k]
        if not m.any() or labels[k] <= 0:
            continue
        class_ids[m] = labels[k]
        instance_ids[m] = int(k) + 1
        scores[m] = confidences[k]


def _empty(shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros(shape, np.uint16), np.zeros(shape, np.int32), np.zeros(shape, np.float32)


def maskrcnn(
    boxes: np.ndarray,
    labels: np.ndarray,
    scores: np.ndarray,
    masks: np.ndarray,
    shape: tuple[int, int],
    class_map: np.ndarray,
    score_threshold: float = 0.5,
    mask_threshold: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h, w = shape
    out = _empty(shape)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    labels = np.asarray(labels).reshape(-1).astype(np.int64)
    scores = np.asarray(scores, np.float64).reshape(-1)
    masks = np.asarray(masks, np.float32)
    if masks.ndim == 4:
        masks = masks[:, 0]
    keep = scores >= score_threshold
    full = []
    for box, m in zip(boxes[keep], masks[keep], strict=True):
        if m.shape == (h, w):
            full.append(m >= mask_threshold)
            continue
        x1, y1, x2, y2 = np.clip(np.round(box).astype(int), 0, [w, h, w, h])
        canvas = np.zeros((h, w), bool)
        if x2 > x1 and y2 > y1:
            zoom = ((y2 - y1) / m.shape[0], (x2 - x1) / m.shape[1])
            canvas[y1:y2, x1:x2] = ndimage.zoom(m, zoom, order=1)[: y2 - y1, : x2 - x1] >= mask_threshold
        full.append(canvas)
    mapped = np.array([class_map[lab] if 0 <= lab < len(class_map) else 0 for lab in labels[keep]], np.int64)
    _paste(*out, full, mapped, scores[keep])
    return out


def _nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> list[int]:
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    while len(order):
        i = int(order[0])
        keep.append(i)
        xx1 = np.maximum(boxes[i, 0], boxes[order[1:], 0])
        yy1 = np.maximum(boxes[i, 1], boxes[order[1:], 1])
        xx2 = np.minimum(boxes[i, 2], boxes[order[1:], 2])
        yy2 = np.minimum(boxes[i, 3], boxes[order[1:], 3])
        inter = np.clip(xx2 - xx1, 0, None) * np.clip(yy2 - yy1, 0, None)
        order = order[1:][inter / np.maximum(area[i] + area[order[1:]] - inter, 1e-9) <= iou]
    return keep


def yolo_seg(
    detections: np.ndarray,
    prototypes: np.ndarray,
    shape: tuple[int, int],
    class_map: np.ndarray,
    score_threshold: float = 0.25,
    mask_threshold: float = 0.5,
    iou_threshold: float = 0.7,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h, w = shape
    out = _empty(shape)
    det = np.asarray(detections, np.float32)[0]  # (4 + nc + k, anchors)
    protos = np.asarray(prototypes, np.float32)[0]  # (k, mh, mw)
    k = protos.shape[0]
    nc = det.shape[0] - 4 - k
    if nc <= 0:
        raise ValueError(
            f"yolo_seg: detections have {det.shape[0]} rows, fewer than 4 + classes + {k} mask coefficients"
        )
    cls_scores = det[4 : 4 + nc].T
    label = cls_scores.argmax(axis=1)
    score = cls_scores.max(axis=1)
    keep = np.flatnonzero(score >= score_threshold)
    if not len(keep):
        return out
    cx, cy, bw, bh = det[0, keep], det[1, keep], det[2, keep], det[3, keep]
    boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
    chosen: list[int] = []
    for c in np.unique(label[keep]):  # class-aware NMS
        sel = np.flatnonzero(label[keep] == c)
        chosen += [int(sel[i]) for i in _nms(boxes[sel], score[keep][sel], iou_threshold)]
    chosen.sort()
    coeffs = det[4 + nc :, keep[chosen]].T  # (n, k)
    logits = coeffs @ protos.reshape(k, -1)
    masks_small = (1 / (1 + np.exp(-logits))).reshape(-1, *protos.shape[1:])
    zoom = (h / protos.shape[1], w / protos.shape[2])
    ys, xs = np.mgrid[0:h, 0:w]
    masks = []
    for m, box in zip(masks_small, boxes[chosen], strict=True):
        full = ndimage.zoom(m, zoom, order=1)[:h, :w] >= mask_threshold
        inside = (xs >= box[0]) & (xs < box[2]) & (ys >= box[1]) & (ys < box[3])
        masks.append(full & inside)
    mapped = np.array([class_map[lab] if lab < len(class_map) else 0 for lab in label[keep][chosen]], np.int64)
    _paste(*out, masks, mapped, score[keep][chosen])
    return out


def semantic_boundary(
    class_logits: np.ndarray,
    boundary_logits: np.ndarray,
    class_map: np.ndarray,
    is_thing: np.ndarray,
    boundary_threshold: float = 0.5,
    min_pixels: int = 20,
    speckle_pixels: int = 0,
    depth: np.ndarray | None = None,
    merge_depth_gap: float = 0.0,
    min_region_score: float = 0.0,
    merge_bridges: str = "any",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    logits = np.asarray(class_logits, np.float32)[0]
    z = logits - logits.max(axis=0, keepdims=True)
    prob = np.exp(z) / np.exp(z).sum(axis=0, keepdims=True)
    net_class = prob.argmax(axis=0)
    score = prob.max(axis=0).astype(np.float32)
    if speckle_pixels > 0:
        # Class specks (connected regions under speckle_pixels) take the class of the nearest
        # larger region: isolated misfires would otherwise add classes the scene does not have.
        keep = np.ones(net_class.shape, bool)
        for c in np.unique(net_class):
            lab, n = ndimage.label(net_class == c)
            small = np.bincount(lab.ravel(), minlength=n + 1) < speckle_pixels
            small[0] = False
            keep &= ~small[lab]
        if keep.any() and not keep.all():
            _, (iy, ix) = ndimage.distance_transform_edt(~keep, return_indices=True)
            net_class, score = net_class[iy, ix], score[iy, ix]
    unsure = np.zeros(net_class.shape, bool)
    if min_region_score > 0:
        # Regions the network is unsure of as a whole (mean top probability under the threshold)
        # are left unknown: a misfire over a whole object otherwise adds a class the scene lacks.
        top = prob.max(axis=0)
        for c in np.unique(net_class):
            lab, n = ndimage.label(net_class == c)
            mean = ndimage.mean(top, lab, index=np.arange(1, n + 1))
            low = np.flatnonzero(np.asarray(mean) < min_region_score) + 1
            if low.size:
                unsure |= np.isin(lab, low)
    class_ids = np.asarray(class_map, np.int64)[net_class].astype(np.uint16)
    class_ids[unsure] = 0
    boundary = 1 / (1 + np.exp(-np.asarray(boundary_logits, np.float32)[0, 0])) >= boundary_threshold
    instance_ids = np.zeros(class_ids.shape, np.int32)
    next_id = 1
    for c in np.unique(class_ids):
        if c == 0 or not is_thing[int(c)]:
            continue
        region = class_ids == c
        cores, n = ndimage.label(region & ~boundary)
        if n == 0:
            continue
        sizes = ndimage.sum(np.ones_like(cores), cores, index=np.arange(1, n + 1))
        big = np.flatnonzero(sizes >= min_pixels) + 1
        cores = np.where(np.isin(cores, big), cores, 0)
        if not big.size:
            continue
        # Boundary pixels (and dropped specks) of this class join the nearest core of the class.
        _, (iy, ix) = ndimage.distance_transform_edt(cores == 0, return_indices=True)
        nearest = cores[iy, ix]
        remap = np.zeros(int(cores.max()) + 1, np.int32)
        remap[big] = np.arange(next_id, next_id + len(big))
        instance_ids[region] = remap[nearest[region]]
        next_id += len(big)
    if depth is not None and merge_depth_gap > 0:
        instance_ids = merge_depth_continuous(
            instance_ids, depth, merge_depth_gap, class_ids=class_ids, bridges=merge_bridges
        )
    return class_ids, instance_ids, score


def merge_depth_continuous(
    instance_ids: np.ndarray,
    depth: np.ndarray,
    relative_gap: float,
    min_share: float = 0.5,
    class_ids: np.ndarray | None = None,
    bridges: str = "any",
) -> np.ndarray:
    """Merge instances whose shared seam is continuous in depth.

    A spurious boundary across a thin part (a chair's post between seat and base) splits one object
    in two whose pixels meet at the same depth; two objects that meet in the image mostly do so at
    a depth step (one occludes the other). Two instances are *joined* when at least ``min_share``
    of the 4-neighbour pixel pairs along their seam differ in depth by at most ``relative_gap`` x
    depth. Every seam between two ids counts, also where their classes differ (the
    semantic_boundary adapter gives each id one class): two pieces of a chair may meet only through
    a post the network calls something else. What keys segments by (class, id), as the mappers and
    the frame metrics do, sees one segment per class, so a join across classes matters only where
    it bridges two instances of one class.

    ``bridges`` says which bridges count. ``"any"``: every join chain merges (two cups standing on
    one table become one cup segment, through the table). ``"smaller"`` (needs ``class_ids``): two
    instances of a class merge when joined directly, or through a chain of other-class instances
    each smaller (in pixels) than both: a post between seat and base bridges, a table under two
    cups does not. Counting only same-class seams lowered map PQ on an office tuning walk
    (0.64 -> 0.60), so the post bridges stay."""
    if bridges not in ("any", "smaller"):
        raise ValueError(f"bridges must be 'any' or 'smaller', not {bridges!r}")
    d = np.asarray(depth, np.float64)
    if d.shape != instance_ids.shape:
        raise ValueError(f"depth is {d.shape}, instances {instance_ids.shape}")
    if bridges == "smaller" and (class_ids is None or np.shape(class_ids) != instance_ids.shape):
        raise ValueError("bridges='smaller' needs class_ids of the instances' shape")
    pairs, flags = [], []
    for a, b, da, db in (
        (instance_ids[:, :-1], instance_ids[:, 1:], d[:, :-1], d[:, 1:]),
        (instance_ids[:-1], instance_ids[1:], d[:-1], d[1:]),
    ):
        seam = (a > 0) & (b > 0) & (a != b)
        if not seam.any():
            continue
        lo, hi = np.minimum(a[seam], b[seam]), np.maximum(a[seam], b[seam])
        za, zb = da[seam], db[seam]
        valid = (za > 0) & (zb > 0) & np.isfinite(za) & np.isfinite(zb)
        pairs.append(lo.astype(np.int64) << 32 | hi.astype(np.int64))
        flags.append(valid & (np.abs(za - zb) <= relative_gap * np.minimum(za, zb)))
    if not pairs:
        return instance_ids
    keys, inverse = np.unique(np.concatenate(pairs), return_inverse=True)
    share = np.bincount(inverse, weights=np.concatenate(flags).astype(float)) / np.bincount(inverse)
    joined = keys[share >= min_share]
    size = int(instance_ids.max()) + 1
    first, second = joined >> 32, joined & 0xFFFFFFFF
    if bridges == "smaller":
        first, second = _bridged_pairs(instance_ids, np.asarray(class_ids), first, second, size)
    graph = sparse.coo_matrix((np.ones(len(first)), (first, second)), shape=(size, size))
    component = csgraph.connected_components(graph, directed=False)[1]
    # Each merged group keeps its smallest id (0, unlabelled, is never joined).
    roots = np.full(component.max() + 1, size)
    np.minimum.at(roots, component, np.arange(size))
    roots = roots[component]
    return roots[instance_ids].astype(instance_ids.dtype)


def _bridged_pairs(
    instance_ids: np.ndarray, class_ids: np.ndarray, first: np.ndarray, second: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Same-class id pairs to merge: joined directly, or through joined other-class ids each
    smaller than both ends (a breadth-first search from each id; a frame has tens of ids)."""
    pixels = np.bincount(instance_ids.ravel(), minlength=size)
    id_class = np.zeros(size, np.int64)
    id_class[instance_ids.ravel()] = class_ids.ravel()
    neighbours: list[list[int]] = [[] for _ in range(size)]
    for x, y in zip(first.tolist(), second.tolist(), strict=True):
        neighbours[x].append(y)
        neighbours[y].append(x)
    same = id_class[first] == id_class[second]
    out_a, out_b = first[same].tolist(), second[same].tolist()
    for start in range(1, size):
        cls, bound = id_class[start], pixels[start]
        seen = {start}
        frontier = [v for v in neighbours[start] if id_class[v] != cls and pixels[v] < bound]
        seen.update(frontier)
        while frontier:
            nxt = []
            for v in frontier:
                for w in neighbours[v]:
                    if w in seen:
                        continue
                    seen.add(w)
                    if id_class[w] == cls:
                        if pixels[w] >= bound:  # the pair's smaller end bounds the bridge (found from that end)
                            out_a.append(start)
                            out_b.append(w)
                    elif pixels[w] < bound:
                        nxt.append(w)
            frontier = nxt
    return np.asarray(out_a, np.int64), np.asarray(out_b, np.int64)
