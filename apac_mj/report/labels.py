"""Who the results are about and how the report calls them: agent kinds and conditions, in a fixed order.

An agent kind's label and colour come from the registry (:mod:`apac_mj.kinds`), a condition's label,
short name and colour from its task file's ``[report]`` table (:class:`~apac_mj.suite.task_spec.TaskSpec`
``report_label``, ``report_short``, ``report_color``). A condition that sets none of them (a task of the
user's) is called by its description and name and gets the first extra colour no other condition of the
report uses. A condition whose task is unknown in this process (results from a task registered
elsewhere) is described by the defaults of :class:`~apac_mj.suite.task_spec.TaskSpec`: its name, the
paper's plane and episode length.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

import pandas as pd

from apac_mj import kinds
from apac_mj.experiments.presets import CONDITIONS
from apac_mj.suite.task_spec import TaskSpec, load_task


class _KindView(Mapping):
    """A live read-only view ``kind name -> AgentKind.<attr>`` of the registry (apac_mj.kinds)."""

    def __init__(self, attr: str) -> None:
        self.attr = attr

    def __getitem__(self, name: str) -> str:
        return getattr(kinds.get(name), self.attr)

    def __iter__(self) -> Iterator[str]:
        return iter(kinds.names())

    def __len__(self) -> int:
        return len(kinds.names())


#: Colour-blind-safe colours for the agent kinds, taken in this order: Okabe & Ito's qualitative palette
#: (orange, bluish green, blue, reddish purple, vermillion, sky blue; its yellow last, its black left out: the
#: figures draw single seeds and means in black), then Paul Tol's "muted" scheme (both designed to stay distinct
#: for protan, deutan and tritan vision; https://jfly.uni-koeln.de/color/, https://personal.sron.nl/~pault/).
SAFE_PALETTE = ("#E69F00", "#009E73", "#0072B2", "#CC79A7", "#D55E00", "#56B4E9",
                "#332288", "#999933", "#882255", "#44AA99", "#CC6677", "#AA4499", "#117733", "#88CCEE", "#DDCC77",
                "#F0E442")


def kind_colors() -> dict[str, str]:
    """Each registered kind's figure colour: its registered ``color`` where that is a :data:`SAFE_PALETTE`
    colour no earlier kind took, else the first palette colour no kind has (in registry order; the built-in kinds
    are registered with palette colours: DDPG orange, SPAC green, APAC blue).
    Distinct for up to ``len(SAFE_PALETTE)`` kinds; past that the palette starts over."""
    names = kinds.names()
    own = {n: kinds.get(n).color.upper() for n in names}
    colors: dict[str, str] = {}
    for n in names:
        if own[n] in SAFE_PALETTE and own[n] not in colors.values():
            colors[n] = own[n]
    free = [c for c in SAFE_PALETTE if c not in colors.values()]
    for i, n in enumerate(n for n in names if n not in colors):
        colors[n] = free[i] if i < len(free) else SAFE_PALETTE[(i - len(free)) % len(SAFE_PALETTE)]
    return colors


class _ColorView(_KindView):
    """A live read-only view ``kind name -> figure colour`` (:func:`kind_colors`)."""

    def __getitem__(self, name: str) -> str:
        kinds.get(name)  # an unknown kind: the registry's error
        return kind_colors()[name]


#: Figure and table labels of the agent kinds (read from the registry) and their colour-blind-safe colours.
AGENT_LABEL, AGENT_COLOR = _KindView("label"), _ColorView("color")

#: How figures call a planner (:mod:`apac_mj.systems`) in "planning (...)"; a planner not named here by its name.
PLANNER_WORDS = {"inverse": "inverse model", "mpc": "MPC through the forward model"}


def planner_label(kind: str) -> str:
    """What the planning actions of ``kind`` are called in figures: "planning (inverse model)" for the paper's
    kinds, "planning (MPC through the forward model)" for the MPC kinds, else after the kind's planner."""
    planner = kinds.get(kind).planner
    return f"planning ({PLANNER_WORDS.get(planner, planner)})"
#: Colours for conditions without their own, taken in this order (none of them a built-in agent's or a
#: shipped condition's).
EXTRA_COLORS = ("tab:gray", "tab:red", "gold", "navy", "darkgoldenrod", "slateblue", "olivedrab", "deeppink",
                "maroon", "steelblue")


def check_kinds(df: pd.DataFrame) -> None:
    """Every agent kind in the results is registered (else it would vanish from the figures)."""
    unknown = sorted(set(df["agent"]) - set(kinds.names()))
    if unknown:
        raise kinds.UnknownKindError(
            f"the results hold agent kind(s) {unknown} that are not registered (registered: "
            f"{', '.join(kinds.names())}); register them with apac_mj.kinds.register before reporting")


def agents(df: pd.DataFrame) -> list[str]:
    """The registered kinds present in ``df``, in registry order; an unregistered one is an error."""
    check_kinds(df)
    return [a for a in kinds.names() if a in set(df["agent"])]


def arbitrating(df: pd.DataFrame) -> list[str]:
    """The kinds in ``df`` whose arbitrator chooses between habit and planning (APAC)."""
    return [a for a in agents(df) if kinds.get(a).arbitrates]


def condition_order(conditions: Iterable[str]) -> list[str]:
    """The conditions present: the paper's in its order, then any other (a user's task) by name."""
    present = set(conditions)
    return [c for c in CONDITIONS if c in present] + sorted(present - set(CONDITIONS))


def condition_spec(condition: str) -> TaskSpec:
    """The task of ``condition``; TaskSpec's defaults under its name where no task of that name is known."""
    try:
        return load_task(condition)
    except KeyError:
        return TaskSpec(name=condition)


def condition_label(condition: str) -> str:
    """How figures and report.md call ``condition``: its ``[report] label``, else its description, else its name."""
    spec = condition_spec(condition)
    return spec.report_label or spec.description or condition


def condition_short(condition: str) -> str:
    """Its short name in tables and axes: its ``[report] short``, else its name."""
    return condition_spec(condition).report_short or condition


def condition_colors(conditions: Iterable[str]) -> dict[str, str]:
    """The colour of each condition present: its ``[report] color``, else the next extra colour that no
    condition present uses (in :func:`condition_order`; past the last one they start over)."""
    order = condition_order(conditions)
    colors = {c: condition_spec(c).report_color for c in order}
    palette = [c for c in EXTRA_COLORS if c not in set(colors.values())] or list(EXTRA_COLORS)
    for i, cond in enumerate(c for c in order if not colors[c]):
        colors[cond] = palette[i % len(palette)]
    return colors


def episodes(n: int) -> str:
    """``n`` with its noun: "1 episode", "30 episodes"."""
    return f"{n} episode" + ("" if n == 1 else "s")
