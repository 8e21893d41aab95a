"""Test-wide settings: one torch thread (the networks here are small; on a shared 2-core machine
two intra-op threads spinning at barriers made updates 10-25x slower), offscreen GL."""
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import torch  # noqa: E402

torch.set_num_threads(1)


# -- agent sizes for tests that build or train agents (``from conftest import TINY``) --------------------

def nets(*hidden: int) -> dict[str, tuple[int, ...]]:
    """The four networks' hidden layers, all ``hidden``: ``nets(16, 16)`` -> ``actor_hidden=(16, 16)``, ..."""
    return {f"{name}_hidden": hidden for name in ("actor", "critic", "forward", "inverse")}


#: A tiny agent for runs that train: 16-unit networks, one babbling and two planning episodes
#: (test_trainer, test_run_dir, test_evaluate, test_faults, test_hooks, test_threads, test_transfers).
TINY = dict(nets(16, 16), batch_size=8, replay_size=64, babbling_episodes=1, planning_episodes=2)
#: Tinier, for runs over every task and kind: 8-unit networks, one planning episode (test_build, test_state_layout;
#: test_geometry builds agents from it and trains none).
TINY8 = dict(nets(8, 8), batch_size=4, replay_size=50, babbling_episodes=1, planning_episodes=1)
#: An agent whose gradients and updates are checked on hand-made minibatches (test_update; test_agent reads it
#: from there): hidden layers of unequal widths (24, 16), so that a weight read transposed fails on its shape.
UNEVEN = dict(nets(24, 16), replay_size=16, batch_size=8)
#: A small model-predictive planner (the kinds that plan through a model; no effect on the others).
TINY_MPC = {"mpc": {"horizon": 2, "candidates": 8, "elites": 2, "iterations": 2, "model_hidden": (8, 8),
                    "model_updates": 1}}


def as_sets(agent: dict) -> list[str]:
    """``agent``'s settings as the command line's ``--set name=value`` options, a tuple written ``16,16``."""
    return [arg for name, value in agent.items()
            for arg in ("--set", f"{name}={','.join(map(str, value)) if isinstance(value, tuple) else value}")]


#: TINY's settings on the command line (``apac-mj train ... *TINY_SETS``: test_faults, test_fault_campaign).
TINY_SETS = as_sets(TINY)


def bench_module(name: str):
    """``bench/<name>.py`` loaded as a module (bench/ is scripts, not a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


#: The frozen tests' and the training's measured wall-time columns: they differ from run to run.
MEASURED_SECONDS = ("habit_seconds", "planning_seconds")


def deterministic(df):
    """``df`` without the measured wall-time columns (habit_seconds, planning_seconds) where it has them,
    for comparing two runs' frames exactly; plan_iterations, which repeats, is kept."""
    return df.drop(columns=[c for c in MEASURED_SECONDS if c in df.columns])


# -- a planner's test double (test_planner, test_planner_properties, test_habit_candidates) ---------------

class ExactPointHand:
    """The exact model of a point hand: an action is ``scale`` cm per tanh unit per axis, always executable, and
    the imagined hand (the state's END entries) moves by it. Subclasses give the habit (``habit_u``) and the
    critic (``value``), and set ``cfg`` and ``layout``."""

    scale = 2.0

    def to_action(self, u: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return u * self.scale

    def executable(self, a: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return a

    def imagine(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        from apac_mj.types import END

        nxt = s.clone()
        nxt[..., END] = s[..., END] + a
        return nxt


def fill_and_update(agent, seed: int = 2, transitions: int = 6):
    """Add ``transitions`` random two-member transitions (a hand within 30 cm, joint velocities ~300 deg/s,
    actions in [-2, 2]) to ``agent``'s replay and update the first member only; returns the agent."""
    g = torch.Generator().manual_seed(seed)
    for _ in range(transitions):
        s = torch.cat([torch.rand(2, 6, generator=g) * 30, torch.randn(2, 2, generator=g) * 300], 1)
        a = torch.rand(2, 2, generator=g) * 4 - 2
        agent.replay.add(s, a, -torch.rand(2, generator=g), s + 1, torch.zeros(2), torch.ones(2, dtype=torch.bool),
                         executed_action=a)
    agent.update(torch.tensor([True, False]))
    return agent


def through_a_checkpoint(state: dict) -> dict:
    """``state`` saved as a checkpoint saves it and loaded back (``weights_only``: tensors and plain data only)."""
    import io

    buf = io.BytesIO()
    torch.save(state, buf)
    buf.seek(0)
    return torch.load(buf, weights_only=True)
