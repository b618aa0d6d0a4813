"""Every built-in stage passes the conformance kit that plugin authors run on theirs."""

from stratamap.core.registry import build_registry
from stratamap.core.testing import parametrize_with_checks

BUILTIN_STAGES = [info.cls for info in build_registry(eps=[], extra_modules=[], autoload=True).all()]


def test_every_kind_has_a_builtin_stage():
    assert {cls.kind for cls in BUILTIN_STAGES} == {"sources", "segmenters", "mappers", "completers", "exporters"}


@parametrize_with_checks(BUILTIN_STAGES)
def test_builtin_stage_conforms(stage_cls, check):
    check(stage_cls)
