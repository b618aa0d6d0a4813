"""The passes of ``clusters`` by name: what each needs to have run before it, and the function that
runs it on the shared :class:`~stratamap.plugins.segmenters.clusters.labelling.Labelling`. The order
they run in is the config's ``passes`` (DEFAULT_PASSES unless set)."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from stratamap.plugins.segmenters.clusters import (
    apart,
    chairs,
    enclosed,
    feet,
    instances,
    kitchen,
    mirrored,
    model,
    oversized,
    parts,
    rename,
    seating,
    segments,
    standing,
    strays,
    stuff,
    supports,
    tops,
    units,
)
from stratamap.plugins.segmenters.clusters.labelling import Labelling


class Pass(NamedTuple):
    """One named pass: the passes whose results it reads, and what it does to the labelling."""

    needs: tuple[str, ...]
    run: Callable[[Labelling], None]


_AFTER_INSTANCES = ("instances",)

PASSES: dict[str, Pass] = {
    "layout": Pass((), stuff.find_stuff),
    "grow_supports": Pass(("layout",), supports.grow),
    "segment": Pass(("layout",), segments.segment_free),
    "split_standing": Pass(("segment",), standing.split),
    "join_supports": Pass(("segment",), supports.join),
    "return_feet": Pass(("join_supports",), supports.give_feet_back),
    "flush_to_layout": Pass(("join_supports",), stuff.flush_to_layout),
    "instances": Pass(("join_supports",), instances.make_instances),
    "drop_strays": Pass(_AFTER_INSTANCES, strays.drop_strays),
    "trim_feet": Pass(_AFTER_INSTANCES, feet.give_back_feet),
    "split_beside_tops": Pass(_AFTER_INSTANCES, tops.split_beside_tops),
    "split_units": Pass(_AFTER_INSTANCES, units.split_units),
    "split_oversized": Pass(_AFTER_INSTANCES, oversized.split_oversized),
    "split_seen_apart": Pass(_AFTER_INSTANCES, apart.split_seen_apart),
    "join_parts": Pass(_AFTER_INSTANCES, parts.join_parts),
    "assemble_chairs": Pass(_AFTER_INSTANCES, chairs.assemble_chairs),
    "join_seating": Pass(_AFTER_INSTANCES, seating.join_seating),
    "join_enclosed": Pass(_AFTER_INSTANCES, enclosed.join_enclosed),
    "cut_below_supports": Pass(_AFTER_INSTANCES, mirrored.cut_below_supports),
    "name_by_model": Pass(_AFTER_INSTANCES, model.name_by_model),
    "rename_by_priors": Pass(_AFTER_INSTANCES, rename.rename_by_priors),
    "counters_need_a_kitchen": Pass(_AFTER_INSTANCES, kitchen.counters_need_a_kitchen),
    "name_after_rules_by_model": Pass(_AFTER_INSTANCES, model.name_after_rules_by_model),
}
