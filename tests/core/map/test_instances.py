"""Grouping map points by instance."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import instance_members, members_of


def test_members_of_lists_each_ids_indices_in_order():
    """One sort gives what ``flatnonzero(ids == k)`` gives for every k; negative ids are nobody's."""
    ids = np.random.default_rng(3).integers(-2, 7, 500)
    groups = members_of(ids, 9)
    assert len(groups) == 9
    for k, group in enumerate(groups):
        assert np.array_equal(group, np.flatnonzero(ids == k))


def test_instance_members_agrees_with_members_of_on_positive_ids():
    ids = np.random.default_rng(4).integers(0, 6, 300)
    groups = members_of(ids, 6)
    assert {k: v.tolist() for k, v in instance_members(ids).items()} == {
        k: groups[k].tolist() for k in range(1, 6) if len(groups[k])
    }
