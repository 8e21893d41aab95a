"""The episode loop's hooks: a base class with no-op methods; plain functions still accepted by train."""
from __future__ import annotations

import numpy as np
import pytest

from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.recording.recording import EpisodeRecorder
from apac_mj.run.rollout import FunctionHook, Hook, as_hooks
from apac_mj.run.trainer import train

from conftest import TINY


class Counting(Hook):
    """Overrides only on_step: the episode starts fall to the base's no-op."""

    def __init__(self, calls: list[str]) -> None:
        self.calls = calls

    def on_step(self, info, vec_env) -> None:
        self.calls.append("hook")


def test_hooks_then_plain_functions_see_every_step(tmp_path):
    calls: list[str] = []
    starts: list[np.ndarray] = []
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=1, checkpoint_every=1, actuation="kinematic",
                      agent=AgentConfig(**TINY))
    train(cfg, tmp_path / "run", progress=False, hooks=[Counting(calls)], on_step=lambda info, env: calls.append("fn"),
          on_episode_start=lambda members, env: starts.append(members))
    assert calls and calls == ["hook", "fn"] * (len(calls) // 2)
    assert len(starts) == 2 and all(m.tolist() == [True] for m in starts)  # babbling, then the training episode


def test_plain_functions_become_one_hook():
    assert as_hooks([]) == []
    seen = []
    (hook,) = as_hooks([], on_step=lambda info, env: seen.append(info))
    assert isinstance(hook, FunctionHook)
    hook.on_episode_start(np.ones(1, dtype=bool), None)  # not given: nothing happens
    hook.on_step("info", None)
    assert seen == ["info"]
    assert isinstance(EpisodeRecorder("unused"), Hook)


def test_a_function_among_the_hooks_is_a_clear_error(tmp_path):
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=1, actuation="kinematic", agent=AgentConfig(**TINY))
    with pytest.raises(TypeError, match="hooks must be apac_mj.run.rollout.Hook instances, got function; "
                                        "pass plain functions as on_step="):
        train(cfg, tmp_path / "run", progress=False, hooks=[lambda info, env: None])
