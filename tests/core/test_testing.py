"""Every built-in stage passes the conformance kit that plugin authors run on theirs."""

import pytest

from stratamap.core.registry import build_registry
from stratamap.core.testing import parametrize_with_checks

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
