"""Metrics against ground truth, one module per family. ``evaluate`` runs every family that applies."""

from __future__ import annotations

from typing import Any

from stratamap.core.stages import PipelineData


def evaluate(data: PipelineData) -> dict[str, Any]:
    """Metrics grouped by family for whatever layers ``data`` holds and its ground truth covers."""
    from stratamap.core.metrics import detection

    gt = data.ground_truth
    out: dict[str, Any] = {}
    if gt is None:
        return out
    if data.map.instances is not None and gt.objects:
        out["detection"] = detection.evaluate_instances(data.map.instances, gt.objects)
    return out
