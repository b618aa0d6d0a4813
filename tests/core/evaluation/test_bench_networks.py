"""The benchmark's results say which families each learned model was trained on and which it never saw."""

from __future__ import annotations

from stratamap.core.evaluation.bench_report import network_lines
from stratamap.plugins.completers.pcn import SHIPPED, network_provenance


def test_results_name_the_trained_and_held_out_families_of_each_variants_network():
    facts = network_provenance(SHIPPED)
    assert facts["trained_on"] and facts["held_out"]
    records = [
        {"variant": "icp_match", "networks": {}},
        {"variant": "pcn", "networks": {"stages[4]": facts}},
        {"variant": "pcn", "networks": {"stages[4]": facts}},
    ]
    (line,) = network_lines(records, ["icp_match", "pcn"])
    assert line.startswith("Variant `pcn`, stage `stages[4]`: network `pcn.onnx`")
    assert all(f"`{family}`" in line for family in facts["trained_on"])
    assert "Held out: " + facts["held_out"] in line
    assert network_lines(records, ["icp_match"]) == []
