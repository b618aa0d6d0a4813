"""scripts/train_fronts.py: the fronts it trains on, cut from the shipped pipeline's instances."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]


def _script():
    spec = importlib.util.spec_from_file_location("train_fronts", REPO / "scripts" / "train_fronts.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_fronts_from_the_detector_pipelines_instances_are_labelled_by_the_scenes_joints_and_cached(tmp_path):
    """With ``instances: detector`` a walk's fronts come from configs/rgbd.yaml's mapping stages; each
    is labelled from the kitchen's own moving parts (some open); the cache gives the same graphs back
    without mapping again."""
    train = _script()
    job = (0, 24, None, "detector", tmp_path, train.SCENE)
    graphs = train.cached_graphs(job)
    labels = np.concatenate([g[3] for g in graphs])
    assert len(graphs) >= 1 and len(labels) >= 3
    from stratamap.core.simulation.virtual_scan import LEVEL2

    assert {LEVEL2[k] for k in labels} & {"cupboard", "drawer", "appliance"}
    (cached,) = list(tmp_path.glob("detector-thresholds-24-0.pkl"))
    before = cached.stat().st_mtime_ns
    again = train.cached_graphs(job)
    assert cached.stat().st_mtime_ns == before
    assert len(again) == len(graphs)
    for a, b in zip(again, graphs, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
