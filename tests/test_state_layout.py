"""The agent's state layout, named once (``apac_mj.layout``): ``[end (2), elbow (2), target (2), extra...]``.

* no positional slice of the state is left outside :mod:`apac_mj.types` (a source scan);
* :func:`apac_mj.agent.arbitration.step_signals` reads the target as the target when the state has extra
  columns (the task's joint velocities), which it once did not (``state[:, 4:]``);
* every registered agent kind trains, end to end, on one task of each variant a kind could meet (the observation's
  layout, the plant's actuation, a stop criterion, a cue, the vision), and every registered task trains one
  arbitrating kind and one that plans through a model (dm_control's suite test: one representative set, not every
  pair): a kind that reads the state by position on a task with extra observations crashes here, and the replay
  memory holds the state as wide as the environment's and its extra observations as the environment gave them.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

import apac_mj
from apac_mj import kinds
from apac_mj.agent.arbitration import step_signals
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import checkpoint
from apac_mj.suite.task_spec import task_names
from apac_mj.suite.vec_env import VecEnv
from apac_mj.types import ARM, ELBOW, END, EXTRA, POSITION_DIM, POSITIONS, TARGET, StepInfo

from conftest import TINY_MPC
from conftest import TINY8 as TINY

PACKAGE = Path(__file__).resolve().parents[1] / "apac_mj"
#: Positional slices of the state: ``[:, 4:]``, ``[b, :4]``, ``[..., 0:2]`` and the like.
POSITIONAL = re.compile(r"\[(?::|b|\.\.\.), ?(?:4:6|4:|:4|:2|0:2|2:4|6:|:6|0:6)\]")
#: Files allowed to slice the state by position: the layout's own module only.
ALLOWED = {PACKAGE / "layout.py"}


def test_the_layout_names():
    state = np.arange(10)[None]  # a state with 4 extra columns
    assert state[:, END].tolist() == [[0, 1]] and state[:, ELBOW].tolist() == [[2, 3]]
    assert state[:, ARM].tolist() == [[0, 1, 2, 3]] and state[:, TARGET].tolist() == [[4, 5]]
    assert state[:, POSITIONS].tolist() == [list(range(6))] and state[:, EXTRA].tolist() == [[6, 7, 8, 9]]
    assert POSITION_DIM == 6 == POSITIONS.stop


def test_no_positional_state_slice_outside_the_layout():
    found = [f"{path.relative_to(PACKAGE.parent)}:{n}: {line.strip()}"
             for path in sorted(PACKAGE.rglob("*.py")) if path not in ALLOWED
             for n, line in enumerate(path.read_text().splitlines(), 1) if POSITIONAL.search(line)]
    assert not found, "read the state through apac_mj.layout's names (END, ELBOW, ARM, TARGET, ...):\n" + \
        "\n".join(found)


def _info(state: np.ndarray, next_state: np.ndarray) -> StepInfo:
    E = len(state)
    z, f = np.zeros(E, dtype=bool), np.zeros(E, dtype=np.float32)
    return StepInfo(episode=np.zeros(E, dtype=np.int64), step=np.zeros(E, dtype=np.int64), active=~z,
                    state=state, true_arm=next_state[:, :4].copy(), target=next_state[:, 4:6].copy(),
                    action=np.zeros((E, 2), dtype=np.float32), habit=~z, delta=f, predicted_arm=next_state[:, :4].copy(),
                    reward=f, distance=f, done=z, reached=z, vision=~z, joint_angles=np.zeros((E, 2)),
                    link_lengths=np.ones((E, 2)), next_state=next_state, terminal=z, zone_radius=0.5)


def test_step_signals_read_the_target_with_extra_columns():
    # [end, elbow, target, 4 joint velocities]; the velocities are large so that reading them as the
    # target would show
    state = np.array([[0, 0, 5, 5, 3, 4, 90, -90, 7, 7],
                      [1, 1, 2, 2, 1, 1, 50, 50, 50, 50]], dtype=np.float32)
    next_state = np.array([[3, 1, 5, 5, 3, 5, 80, 80, 80, 80],
                           [4, 5, 2, 2, 1, 1, -9, -9, -9, -9]], dtype=np.float32)
    sig = step_signals(_info(state, next_state))
    np.testing.assert_allclose(sig["before"].numpy(), [5.0, 0.0])   # |(0,0)-(3,4)|, |(1,1)-(1,1)|
    np.testing.assert_allclose(sig["after"].numpy(), [4.0, 5.0])    # |(3,1)-(3,5)|, |(4,5)-(1,1)|
    assert sig["before"].dtype == sig["after"].dtype == torch.float32


def variant(task: str) -> tuple:
    """What a kind could meet differently from one task to another: the observation's layout (the state's width, the
    extra observations' names), the plant's actuation, a stop criterion, a cue, the vision."""
    env = VecEnv(task, [0])
    spec = env.spec
    return (env.sizes.state_dim, tuple(env.extra_names), spec.plant.actuation, spec.stop_speed is not None,
            spec.cued, spec.vision)


#: The tasks that stand for their variant where it holds one (the architecture review's five); any other variant
#: by its shortest task name. Today's 20 tasks make 8 variants, not 5: the review's five, and the compliant plant
#: (changing_target_compliant_gravity), intermittent vision and noisy vision (changing_target_intermittent,
#: changing_target_noisy), which a kind meets on no other task.
PREFERRED = ("changing_target", "changing_target_torque", "changing_target_torque_stop", "cued_targets",
             "changing_target_occluded")


def one_task_per_variant(tasks: list[str]) -> list[str]:
    """One task of each :func:`variant` among ``tasks`` (a preferred one where the variant holds one), sorted."""
    groups: dict[tuple, list[str]] = {}
    for task in tasks:
        groups.setdefault(variant(task), []).append(task)
    return sorted(min(g, key=lambda t: (t not in PREFERRED, len(t), t)) for g in groups.values())


#: One task of each variant: every kind trains on these.
VARIANTS = one_task_per_variant(task_names())
#: The kinds that train on every task: one arbitrating kind, and one whose planner is a model's.
EVERY_TASK_KINDS = ("apac", "apac_voc")
#: (kind, task): every kind x one task per variant, then every task x EVERY_TASK_KINDS, each pair once.
CASES = list(dict.fromkeys([*((k, t) for k in kinds.names() for t in VARIANTS),
                            *((k, t) for t in task_names() for k in EVERY_TASK_KINDS)]))


#: Episodes of 8 steps, not 30: the layout is the same at every step, and two episodes of 8 still fill 16 replay
#: rows, each checked against what the environment gave.
SHORT = {"steps_per_episode": 8}


def test_the_variants_keep_the_layouts_apart():
    """The five tasks whose layout, plant, stop criterion or cue differ stand for five variants (a ``variant`` that
    no longer tells them apart would shrink the matrix below silently)."""
    assert set(PREFERRED) <= set(VARIANTS)
    assert {t for _, t in CASES} == set(task_names()) and {k for k, _ in CASES} == set(kinds.names())


@pytest.mark.parametrize("kind, task", CASES)
def test_every_kind_trains_on_every_variant(tmp_path, kind, task):
    """One babbling episode (the rules observe every step), then one arbitrated episode (no planning phase: the
    kind's rule decides from the first training step). The replay memory's states are as wide as the environment's
    (its dm_env specs), and their extra columns are the extra observations the environment gave at each step."""
    cfg = TrainConfig(task=task, seeds=(0,), episodes=1, checkpoint_every=1, task_overrides=SHORT,
                      agent=AgentConfig(kind=kind, **{**TINY, "planning_episodes": 0}, params=TINY_MPC))
    seen: list[tuple[int, np.ndarray]] = []  # each step: the environment's state width and extra observations
    run = apac_mj.train(cfg, tmp_path, progress=False,
                        on_step=lambda info, env: seen.append((env.sizes.state_dim, env.extra[0].copy())))
    metrics = pd.read_parquet(run / "metrics.parquet")
    train = metrics[metrics.phase == "train"]
    assert train.groupby("seed").size().to_dict() == {0: 1} and (metrics.phase == "babbling").sum() == 1
    assert all(math.isfinite(r) for r in train["return"])
    replay = checkpoint.load(run / "checkpoints" / "latest.pt")["agent"]["replay"]
    (width,) = {w for w, _ in seen}
    stored, n = replay["data"]["next_state"][0], replay["count"][0]  # a ring: [capacity, width]
    assert stored.shape == (TINY["replay_size"], width) and replay["data"]["state"].shape[-1] == width
    assert n == min(len(seen), TINY["replay_size"])  # one transition a step
    stored = torch.roll(stored, -replay["ptr"][0], 0)[-n:]  # oldest first
    np.testing.assert_allclose(stored[:, EXTRA].numpy(), np.array([e for _, e in seen[-n:]]).reshape(n, -1),
                               rtol=1e-6)
