"""Pass ``counters_need_a_kitchen`` (``recognize``): a unit the priors called a counter by its size
alone (a solid unit with a flat top at worktop height) is as likely a chest of drawers or a storage
unit; where nothing in the map says kitchen, it is a cabinet."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.priors import KITCHEN_APPLIANCES, UNIT, WORKTOP
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import counter_run, fits_class


def counters_need_a_kitchen(lab: Labelling) -> None:
    """Where nothing in the map says kitchen (no counter run longer than one unit, ``counter_run``; no
    counter another source named; no KITCHEN_APPLIANCES), units named counter by their shape are
    cabinets: those no longer than one unit, and longer ones with no one top along them (two units
    that came out as one). Sets ``class_ids`` and ``naming``; each change is noted (``recognition``)."""
    from stratamap.core.map.instances import instance_members

    vocab = lab.vocab
    if not lab.cfg.recognize or lab.cfg.naming == "model" or WORKTOP not in vocab or UNIT not in vocab:
        return
    short = []
    for iid, sel in instance_members(lab.instance_ids).items():
        name = vocab.name(int(np.bincount(lab.class_ids[sel]).argmax()))
        if name in KITCHEN_APPLIANCES:
            return
        if name != WORKTOP:
            continue
        shape = lab.shape(sel)
        if counter_run(shape) or lab.naming.get(iid, ("labels", ""))[0] != "shape":
            return
        if fits_class(UNIT, shape):
            short.append((iid, sel))
    changes = []
    reason = "a counter's size, but nothing in the map says kitchen (no counter run, no appliance): a unit"
    for iid, sel in short:
        lab.relabel(sel, cls=vocab.id(UNIT))
        changes.append({"instance": iid, "from": WORKTOP, "to": UNIT, "why": reason})
        lab.naming[iid] = ("context", f"{reason} (was {WORKTOP})")
    lab.note("recognition", changes)
