"""docs/architecture.md's module table is the map of the package: every module of ``apac_mj`` has a row, and
every row names a module that exists (issue 40: the page had drifted 9 modules behind the code).

A row's first cell is the module's path from the repository root in backticks, ``apac_mj/run/trainer.py``.
"""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
SECTION = "## Modules"
ROW = re.compile(r"^\|\s*`(apac_mj/[^`]+\.py)`\s*\|")


def package_modules() -> set[str]:
    """Every ``apac_mj/**/*.py``, as a path from the repository root."""
    return {p.relative_to(ROOT).as_posix() for p in (ROOT / "apac_mj").rglob("*.py")
            if "__pycache__" not in p.parts}


def table_modules() -> list[str]:
    """The modules the table names, in its order (from the "## Modules" heading to the next heading)."""
    text = DOC.read_text()
    assert SECTION + "\n" in text, f"{DOC.relative_to(ROOT)} has no {SECTION!r} section: the module table is in it"
    section = text.split(SECTION + "\n", 1)[1].split("\n## ", 1)[0]
    return [m.group(1) for line in section.splitlines() if (m := ROW.match(line))]


def test_the_table_reads_rows() -> None:
    named = table_modules()
    assert "apac_mj/run/trainer.py" in named and "apac_mj/__init__.py" in named, named[:5]


def test_every_module_is_in_the_architecture_table() -> None:
    missing = sorted(package_modules() - set(table_modules()))
    assert not missing, (
        f"modules missing from the module table of docs/architecture.md ({SECTION!r}): {', '.join(missing)}. "
        "Add one row each, in its layer's place: | `apac_mj/<path>.py` | one line from its docstring |")


def test_the_table_names_only_modules_that_exist() -> None:
    gone = sorted(set(table_modules()) - package_modules())
    assert not gone, (f"docs/architecture.md's module table ({SECTION!r}) names modules that do not exist: "
                      f"{', '.join(gone)}. Remove their rows, or rename them to where the code moved.")


def test_each_module_has_one_row() -> None:
    named = table_modules()
    twice = sorted({m for m in named if named.count(m) > 1})
    assert not twice, f"docs/architecture.md's module table lists these more than once: {', '.join(twice)}"
