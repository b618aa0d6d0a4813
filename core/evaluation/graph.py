"""Contact graph against the ground truth (functional-scenes paper, Table 5).

Predicted objects are matched to ground-truth objects (see ``detection``). The graph edit
distance counts the edits that turn one support tree into the other: a matched object whose
supporter differs (wrong support), a ground-truth object with no prediction (missing node and
its edge), a prediction with no ground truth (extra node and its edge). With node
correspondences fixed by the matching, this is the exact edit distance between the two trees.
"""

from __future__ import annotations

from typing import Any

from stratamap.core.evaluation.detection import match_boxes
from stratamap.core.map.layers import ContactGraph, ObjectInstances


def evaluate_graph(
    pred: ContactGraph, instances: ObjectInstances, truth: ContactGraph, gt_objects: list
) -> dict[str, Any]:
    insts = list(instances)
    matches = match_boxes([(i.class_name, i.box) for i in insts], [(o.class_name, o.box()) for o in gt_objects])
    to_gt = {insts[p].id: gt_objects[g].id for p, g in matches}

    def layout(node: Any) -> Any:
        return "floor" if isinstance(node, str) and node.startswith("floor") else node

    wrong = 0
    for pid, gid in to_gt.items():
        pp = pred.parent(pid) if pid in pred.support else None
        gp = truth.parent(gid) if gid in truth.support else None
        mapped = to_gt.get(pp, pp) if isinstance(pp, int) else layout(pp)
        if mapped != layout(gp):
            wrong += 1
    missing = len(gt_objects) - len(matches)
    extra = len(insts) - len(matches)
    return {"ged": wrong + 2 * missing + 2 * extra, "wrong_support": wrong, "missing": missing, "extra": extra}
