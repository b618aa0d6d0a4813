"""Every built-in stage passes the conformance kit that plugin authors run on theirs."""

from pathlib import Path

import pytest

from stratamap.core import Completer, PipelineData, StageConfig
from stratamap.core.registry import build_registry
from stratamap.core.testing import (
    check_deterministic,
    check_inputs_untouched,
    check_verb_contract,
    parametrize_with_checks,
)

BUILTIN_STAGES = [info.cls for info in build_registry(eps=[], extra_modules=[], autoload=True).all()]
#: Built-in stages whose library comes with an extra: checked where it is installed, skipped elsewhere.
EXTRA_MODULES = {"usd": "pxr"}


def test_every_kind_has_a_builtin_stage():
    assert {cls.kind for cls in BUILTIN_STAGES} == {"sources", "segmenters", "mappers", "completers", "exporters"}


@parametrize_with_checks(BUILTIN_STAGES)
def test_builtin_stage_conforms(stage_cls, check):
    if stage_cls.name in EXTRA_MODULES:
        pytest.importorskip(EXTRA_MODULES[stage_cls.name])
    check(stage_cls)


class _Shifting(Completer[StageConfig]):
    """Moves every object's points 1 cm in place (a fault the kit must catch)."""

    name = "shifting"
    Config = StageConfig

    def complete(self, data: PipelineData) -> dict:
        for inst in data.map.instances:
            inst.points += 0.01
        return {"instances": data.map.instances.copy()}


class _Counting(Completer[StageConfig]):
    """Drops as many objects as it has run before (a fault the kit must catch)."""

    name = "counting"
    Config = StageConfig
    runs = 0

    def complete(self, data: PipelineData) -> dict:
        type(self).runs += 1
        insts = data.map.instances.copy()
        return {"instances": type(insts)(list(insts)[type(self).runs :])}


def test_the_checks_that_share_a_run_still_catch_a_stage_that_edits_its_inputs_or_drifts():
    """The verb-contract, untouched-inputs and determinism checks share the stage's first run: in the
    kit's order each still fails the stage it is there to fail, and passes the other."""
    check_verb_contract(_Shifting)
    with pytest.raises(AssertionError, match="modified its input layers"):
        check_inputs_untouched(_Shifting)
    check_deterministic(_Shifting)
    check_verb_contract(_Counting)
    check_inputs_untouched(_Counting)
    with pytest.raises(AssertionError, match="different outputs"):
        check_deterministic(_Counting)
    assert _Counting.runs == 2


@pytest.mark.slow
def test_the_kit_and_the_example_recordings_leave_no_folder_behind():
    """The conformance kit's export folders and a source's example recording outlive the call that
    made them (the checks read them; a cached stage's parameters name them) and are gone when the
    process exits: each `make test` used to leave some 40 behind in the temporary folder."""
    import subprocess
    import sys

    code = (
        "from stratamap.core.testing import run_stage, example_params\n"
        "from stratamap.plugins.exporters.ply import PLYExporter\n"
        "from stratamap.plugins.sources.pointcloud import PointCloudSource\n"
        "_, _, out = run_stage(PLYExporter)\n"
        "cloud = example_params(PointCloudSource)['path']\n"
        "import pathlib\n"
        "assert any(out.iterdir()) and pathlib.Path(cloud).is_file()\n"
        "print(out); print(cloud)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out, cloud = (Path(line) for line in run.stdout.split())
    assert not out.exists() and not cloud.parent.exists()
