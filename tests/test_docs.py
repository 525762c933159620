"""The README documents what the code does: schema table, CI command, config groups."""

from __future__ import annotations

from experiments.schema import markdown_table
from tests.conftest import PROJECT_ROOT
from ttc.settings import AXES

README = (PROJECT_ROOT / "README.md").read_text()


def test_readme_schema_table_is_current() -> None:
    assert markdown_table() in README, "regenerate with: python -m experiments.schema"


def test_readme_test_command_is_the_ci_command() -> None:
    ci = (PROJECT_ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci in README


def test_every_config_group_value_is_listed() -> None:
    for group in AXES:
        for option in sorted((PROJECT_ROOT / "conf" / group).glob("*.yaml")):
            assert option.stem in README, f"{group}/{option.stem} missing from README"
