"""docs/experiments.md's preset table states what each preset file holds: one row per preset of tasks/presets/, its
agents, conditions, seeds x episodes and tests as the presets registry reads them (issue 45: the table said 3 seeds
for `dynamics`, whose file has 5, and lacked the `planning` presets). A failure prints the row to paste."""
from __future__ import annotations

import re
from pathlib import Path

from apac_mj.experiments.presets import CONDITIONS, Preset, load_preset, preset_names

DOC = Path(__file__).resolve().parents[1] / "docs" / "experiments.md"
#: The table's header: the generated columns, then the hand-written one.
HEADER = "| preset | agents | conditions | seeds x episodes | tests | meant for |"


def _names(values: tuple[str, ...]) -> str:
    return ", ".join(f"`{v}`" for v in values)


def _conditions(values: tuple[str, ...]) -> str:
    if values == CONDITIONS:
        return "the paper's 4"
    return _names(values) if values else "none (generalization cells only)"


def _tests(p: Preset) -> str:
    t, out = p.tests, []
    if t.grid:
        out.append("grid")
    if t.occluded:
        out.append("occluded")
    if t.generalization and t.generalization_conditions:
        out.append(f"generalization ({_conditions(t.generalization_conditions)})")
    if t.limit:
        out.append(f"first {t.limit} targets")
    return ", ".join(out) or "none"


def preset_row(name: str) -> list[str]:
    """The generated cells of preset ``name``'s row."""
    p = load_preset(name)
    return [f"`{name}`", _names(p.agents), _conditions(p.conditions), f"{len(p.seeds)} x {p.episodes}", _tests(p)]


def doc_rows() -> dict[str, list[str]]:
    """The table's rows by preset name: its cells, stripped."""
    text = DOC.read_text()
    assert HEADER in text, f"docs/experiments.md lost the preset table's header {HEADER!r}"
    table = text.split(HEADER, 1)[1].split("\n\n", 1)[0]
    rows = {}
    for line in table.strip().splitlines()[1:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        rows[re.sub(r"`", "", cells[0])] = cells
    return rows


def test_one_row_per_preset():
    assert sorted(doc_rows()) == preset_names()


def test_rows_state_what_the_files_hold():
    rows = doc_rows()
    for name in preset_names():
        expected = preset_row(name)
        assert rows[name][:5] == expected, ("docs/experiments.md's row for preset " + name + " should start\n| "
                                           + " | ".join(expected) + " |")
        assert rows[name][5], f"preset {name}: say what it is meant for"


def test_a_stale_row_is_caught():
    """The dynamics preset's old row (3 seeds) is not what its file holds."""
    assert preset_row("dynamics")[3] == f"{len(load_preset('dynamics').seeds)} x 200" != "3 x 200"
