"""The suite's own scheduling: the files it starts first exist (a renamed file would silently lose
its place and could again run alone at the end of `make test`)."""

from tests.conftest import LONGEST_FILES, REPO


def test_every_file_started_first_exists():
    missing = [name for name in LONGEST_FILES if not (REPO / "tests" / name).is_file()]
    assert not missing, missing
