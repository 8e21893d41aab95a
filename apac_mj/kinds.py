"""The registry of agent kinds: the one place that says what ``ddpg``, ``spac`` and ``apac`` are.

An agent kind is a name (``AgentConfig.agent``) with what the rest of the
project needs to know about it: its label and colour in figures, the
arbitrator that decides between the actor and the inverse model, which of the
two it uses, and whether it can act in the dark (the occluded-vision test
runs only for kinds that can). Every module asks the registry; none tests a
kind's name. A new kind is one :func:`register` call from any code, inside the
package or not (docs/extending.md)::

    from apac_mj import kinds
    from apac_mj.agent.arbitration import DeltaArbitrator

    kinds.register(kinds.AgentKind("apac_strict", "APAC (strict)", "tab:purple",
                                   arbitrator=lambda cfg: DeltaArbitrator(cfg)))

Kinds registered at run time exist in the process that registered them: the
local executor with one worker and the library functions see them; process
pools and Ray workers only if the registering module is imported there too.
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:
    from apac_mj.agent.arbitration import Arbitrator
    from apac_mj.config import AgentConfig


class UnknownKindError(ValueError, KeyError):
    """An agent kind that is not registered (a ValueError for config checks, a KeyError for look-ups)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


@dataclasses.dataclass(frozen=True)
class AgentKind:
    """One kind of agent and everything the project needs to know about it."""

    #: The name used in configs, presets, run directories and the command line.
    name: str
    #: How figures and tables call it.
    label: str
    #: Its matplotlib colour in figures.
    color: str
    #: ``AgentConfig -> Arbitrator``: builds the rule that decides between habit and planning.
    arbitrator: Callable[[AgentConfig], Arbitrator]
    #: The actor (habit) can act.
    uses_habit: bool = True
    #: The inverse model (planning) can act.
    uses_planner: bool = True
    #: The kind can act without vision (it has a planner moving on the forward model's estimate), so the
    #: occluded-vision test applies to it.
    acts_occluded: bool = True
    #: Why the occluded test does not apply (when ``acts_occluded`` is False); shown in eval summaries.
    occluded_reason: str = ""

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ValueError(f"agent kind name must be a non-empty identifier, got {self.name!r}")
        if not (self.uses_habit or self.uses_planner):
            raise ValueError(f"agent kind {self.name!r} must use the habit, the planner or both")
        if not callable(self.arbitrator):
            raise ValueError(f"agent kind {self.name!r}: arbitrator must be callable (AgentConfig -> Arbitrator)")

    @property
    def arbitrates(self) -> bool:
        """Both controllers can act, so the arbitration (habit share) is worth showing."""
        return self.uses_habit and self.uses_planner


_KINDS: dict[str, AgentKind] = {}


def register(kind: AgentKind, replace: bool = False) -> AgentKind:
    """Add ``kind`` to the registry (after the kinds already there); a taken name needs ``replace=True``."""
    if kind.name in _KINDS and not replace:
        raise ValueError(f"agent kind {kind.name!r} is already registered (pass replace=True to redefine it)")
    _KINDS[kind.name] = kind
    return kind


def unregister(name: str) -> None:
    """Remove a kind registered at run time (tests, notebooks); the built-in ones stay."""
    if name in BUILTIN:
        raise ValueError(f"the built-in agent kind {name!r} cannot be removed")
    get(name)
    del _KINDS[name]


def get(name: str) -> AgentKind:
    """The registered kind ``name``; an unknown name is an error listing the known ones."""
    try:
        return _KINDS[name]
    except (KeyError, TypeError):
        raise UnknownKindError(f"unknown agent kind {name!r}; registered kinds: {', '.join(_KINDS)} "
                               "(apac_mj.kinds.register adds one)") from None


def names() -> tuple[str, ...]:
    """Every registered kind's name, in registration order (the built-in ones first)."""
    return tuple(_KINDS)


def arbitrator_for(cfg: AgentConfig, state: dict | None = None) -> Arbitrator:
    """The arbitrator of ``cfg.agent``'s kind, built from ``cfg``, with the running statistics ``state``
    (a checkpoint's ``"arbitrator"`` entry) loaded where given (:func:`apac_mj.agent.arbitration.restore`)."""
    from apac_mj.agent.arbitration import restore

    arbitrator = get(cfg.agent).arbitrator(cfg)
    restore(arbitrator, state)
    return arbitrator


def _builtin(name: str) -> Callable[[AgentConfig], Arbitrator]:
    """A factory of ``apac_mj.agent.arbitration.<name>``, imported when first used (this module stays torch-free)."""

    def make(cfg: AgentConfig) -> Arbitrator:
        from apac_mj.agent import arbitration as arbitrator

        return getattr(arbitrator, name)(cfg)

    make.__qualname__ = make.__name__ = name
    return make


register(AgentKind("ddpg", "DDPG", "tab:orange", _builtin("AlwaysHabit"), uses_planner=False, acts_occluded=False,
                   occluded_reason="DDPG has no forward model to move on"))
register(AgentKind("spac", "SPAC", "tab:green", _builtin("AlwaysPlan"), uses_habit=False))
register(AgentKind("apac", "APAC", "tab:blue", _builtin("DeltaArbitrator")))
# Beyond the paper (docs/arbitrators.md): APAC's two systems under other arbitration rules.
register(AgentKind("apac_uncertainty", "APAC-U (uncertainty)", "tab:pink", _builtin("UncertaintyArbitrator")))
register(AgentKind("apac_reliability", "APAC-R (reliability)", "sienna", _builtin("ReliabilityArbitrator")))
register(AgentKind("apac_speed_accuracy", "APAC-SA (speed-accuracy)", "crimson",
                   _builtin("SpeedAccuracyArbitrator")))
def _vision_aware(cfg: AgentConfig) -> Arbitrator:
    """The vision-aware rule over ``cfg.vision_aware_base``'s rule (built with the default base, so that
    naming a vision-aware kind as the base is refused instead of recursing)."""
    import dataclasses

    from apac_mj.agent.arbitration import VisionAwareArbitrator

    base_cfg = dataclasses.replace(cfg, vision_aware_base=DEFAULT)
    return VisionAwareArbitrator(cfg, base=get(cfg.vision_aware_base).arbitrator(base_cfg))


register(AgentKind("apac_vision", "APAC-V (vision-aware)", "darkturquoise", _vision_aware))
#: The kinds registered here (the built-in ones: they cannot be removed).
BUILTIN = names()
#: The paper's kinds (the default agents of a preset).
PAPER_KINDS = BUILTIN[:3]
#: The default kind.
DEFAULT = "apac"
