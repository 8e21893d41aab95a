"""How the forced-response test names what it tested (torch-free, for reports and the command line).

A *variant* is the agent kind's own rule (the kind's name) or, for a kind whose rule reads the last
transition's delta (the paper's delta rule), that rule on the delta of the habit's imagined transition (the
kind's name with :data:`IMAGINED` appended): the only delta a trial's first decision could read.
"""
from __future__ import annotations

from typing import Sequence

from apac_mj import kinds

#: The suffix of the variant that reads the delta of the habit's imagined transition.
IMAGINED = "_imagined"


def base_kind(variant: str) -> str:
    """The agent kind a variant was trained as."""
    if variant in kinds.names() or not variant.endswith(IMAGINED):
        return variant
    return variant[: -len(IMAGINED)]


def label(variant: str, tested: Sequence[str] = ()) -> str:
    """How figures, tables and recordings call ``variant`` (its kind's label, what it can use, which delta the
    rule read where ``tested`` holds both of a delta rule's variants)."""
    kind = kinds.get(base_kind(variant))
    if variant.endswith(IMAGINED) and variant != kind.name:
        return f"{kind.label}, delta of the imagined transition"
    if variant + IMAGINED in tested:
        return f"{kind.label}, paper's delta rule"
    if not kind.uses_planner:
        return f"{kind.label} (habit only)"
    if not kind.uses_habit:
        return f"{kind.label} (planning only)"
    return kind.label


def order(variants: Sequence[str]) -> list[str]:
    """``variants`` in the registry's order of their kinds, each kind's own rule before its imagined one."""
    registered = kinds.names()

    def key(v: str) -> tuple[int, bool]:
        b = base_kind(v)
        return (registered.index(b) if b in registered else len(registered), v != b)

    return sorted(set(variants), key=key)
