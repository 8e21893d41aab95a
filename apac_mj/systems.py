"""The registries of the agent's exchangeable systems: planners and integrators, chosen by name.

A **planner** is the planning system's proposal (an :class:`apac_mj.types.Planner`): the paper's inverse model
(``"inverse"``) or model-predictive control through a learned dynamics model (``"mpc"``). An agent kind names
its planner (``AgentKind.planner``). An **integrator** makes the state estimate the agent acts on (an
:class:`apac_mj.types.Integrator`); a run names it (``AgentConfig.integrator``). Both are registered as agent
kinds are, from any code, in one call (docs/extending.md)::

    from apac_mj import systems

    systems.register_planner(systems.PlannerKind("greedy", build=lambda cfg, task: GreedyPlanner(task)))
    systems.register_integrator(systems.IntegratorKind("last_seen", build=lambda cfg, E, obs_std, device:
                                                       LastSeen(E, device)))

The builder (:mod:`apac_mj.run.build`) asks these registries what to build; nothing else tests a planner's or
an integrator's name. This module is torch-free (the configuration and the command line read it); the built-in
factories import their classes when first called.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable

from apac_mj import rules
from apac_mj.rules import KalmanParams, MPCParams
from apac_mj.util.registry import Registry

# The factories' types are named in strings only: the configuration imports this module, and the contracts
# (apac_mj.types: Planner, PlanningTask, Integrator) name the configuration, so no import of them here, even
# for annotations (tests/test_imports.py: no cycle at type level).


@dataclasses.dataclass(frozen=True)
class PlannerKind:
    """A planning system and what the rest of the project needs to know about it."""

    #: The name an agent kind gives (``AgentKind.planner``).
    name: str
    #: ``(AgentConfig, PlanningTask) -> Planner``: the planner for the run's members and task.
    build: Callable[[Any, Any], Any]
    #: The table of its parameters (:mod:`apac_mj.rules`; ``agent.<table>.<field>``); None: none.
    params: type | None = None
    #: It plans through the agent's dynamics model: the builder gives the agent one, set by ``agent.mpc``'s
    #: ``model_*`` fields, trained beside the paper's networks.
    model: bool = False
    #: The field of :class:`apac_mj.run.timing.Timing` that says how long one of its iterations takes in the
    #: forced-response test (ms).
    iteration_ms: str = "inverse_pass_ms"

    def __post_init__(self) -> None:
        _check_name("planner", self.name)
        if not callable(self.build):
            raise ValueError(f"planner {self.name!r}: build must be callable (AgentConfig, PlanningTask -> Planner)")


@dataclasses.dataclass(frozen=True)
class IntegratorKind:
    """An integrator and its parameters."""

    #: The name a run gives (``AgentConfig.integrator``).
    name: str
    #: ``(AgentConfig, E, observation noise std in cm, device) -> Integrator``.
    build: Callable[[Any, int, float, Any], Any]
    #: The table of its parameters (:mod:`apac_mj.rules`; ``agent.<table>.<field>``); None: none.
    params: type | None = None

    def __post_init__(self) -> None:
        _check_name("integrator", self.name)
        if not callable(self.build):
            raise ValueError(f"integrator {self.name!r}: build must be callable (AgentConfig, E, obs_std, device "
                             "-> Integrator)")


def _check_name(what: str, name: str) -> None:
    if not isinstance(name, str) or not name or not name.replace("_", "").isalnum():
        raise ValueError(f"{what} name must be a non-empty identifier, got {name!r}")


PLANNERS: Registry[PlannerKind] = Registry(
    "planner", unknown="unknown planner {name!r}; registered planners: {names} (apac_mj.systems.register_planner "
                       "adds one)")
INTEGRATORS: Registry[IntegratorKind] = Registry(
    "integrator", unknown="unknown integrator {name!r}; registered integrators: {names} "
                          "(apac_mj.systems.register_integrator adds one)")


def add(registry: Registry, kind: Any, replace: bool = False) -> Any:
    """Add ``kind`` (a named item with a ``params`` table or None) to ``registry``, its table to every
    AgentConfig (:func:`apac_mj.rules.register`); a taken name needs ``replace=True``."""
    if not replace:
        registry.check_new(kind.name)
    if kind.params is not None:
        rules.register(kind.params)
    return registry.replace(kind.name, kind)


def register_planner(kind: PlannerKind, replace: bool = False) -> PlannerKind:
    """Add ``kind`` (and its parameter table) to the planners; a taken name needs ``replace=True``."""
    return add(PLANNERS, kind, replace)


def register_integrator(kind: IntegratorKind, replace: bool = False) -> IntegratorKind:
    """Add ``kind`` (and its parameter table) to the integrators; a taken name needs ``replace=True``."""
    return add(INTEGRATORS, kind, replace)


def unregister(name: str) -> None:
    """Remove a planner or an integrator registered at run time (tests, notebooks); the built-in ones stay."""
    if name in BUILTIN:
        raise ValueError(f"the built-in system {name!r} cannot be removed")
    (PLANNERS if name in PLANNERS else INTEGRATORS).unregister(name)


def planner(name: str) -> PlannerKind:
    """The registered planner ``name`` (an unknown one: a KeyError listing the registered ones)."""
    return PLANNERS.get(name)


def integrator(name: str) -> IntegratorKind:
    """The registered integrator ``name`` (an unknown one: a KeyError listing the registered ones)."""
    return INTEGRATORS.get(name)


def integrator_names() -> tuple[str, ...]:
    return INTEGRATORS.names()


# The built-in factories import their classes when first called (this module stays torch-free).
def _inverse(cfg: Any, task: Any) -> Any:
    from apac_mj.agent.planner import InversePlanner

    return InversePlanner()


def _mpc(cfg: Any, task: Any) -> Any:
    from apac_mj.agent.planner import MPCPlanner

    return MPCPlanner(cfg.params[MPCParams.table], task.seeds, task.action_dim, task.zone_radius, task.stop_speed)


def _pass_through(cfg: Any, E: int, obs_std: float, device: Any) -> Any:
    from apac_mj.agent.integrator import PassThrough

    return PassThrough(E, device)


def _kalman(cfg: Any, E: int, obs_std: float, device: Any) -> Any:
    from apac_mj.agent.integrator import KalmanIntegrator

    p: KalmanParams = cfg.params[KalmanParams.table]
    return KalmanIntegrator(E, obs_std, process_floor=p.process_floor, window=p.window,
                            initial_process_var=p.initial_process_var, device=device)


register_planner(PlannerKind("inverse", _inverse))
register_planner(PlannerKind("mpc", _mpc, params=MPCParams, model=True, iteration_ms="mpc_iteration_ms"))
register_integrator(IntegratorKind("pass_through", _pass_through))
register_integrator(IntegratorKind("kalman", _kalman, params=KalmanParams))
#: The built-in planners and integrators (they cannot be removed).
BUILTIN = (*PLANNERS.names(), *INTEGRATORS.names())
