"""The ensemble on a device: a training step reads values back to the host a fixed number of times, whatever E.

Counted with a ``TorchFunctionMode`` that sees every host read of a tensor (``.cpu()``, ``.numpy()``,
``.item()``, ``.tolist()``, ``bool()``, ``float()``, ``np.asarray``, ``.to("cpu")``). On the CPU every
tensor is on the host, so there the test checks that no read is per member (the count per step does
not grow with E); on a CUDA machine (``bench/gpu_check.sh`` runs this file) it also counts the reads
of tensors on the GPU: the action for MuJoCo, the step's record and the losses, one transfer each.
"""
from __future__ import annotations

import collections

import numpy as np
import pytest
import torch
from torch.overrides import TorchFunctionMode

from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig
from apac_mj.run.build import episode_loop
from apac_mj.run.rollout import EpisodeState, to_host
from apac_mj.suite.vec_env import VecEnv

from conftest import TINY

READS = {"cpu", "numpy", "item", "tolist", "__bool__", "__array__", "__float__", "__int__", "__index__"}
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


class HostReads(TorchFunctionMode):
    """Counts host reads by the device of the tensor read."""

    def __init__(self) -> None:
        super().__init__()
        self.by_device: collections.Counter = collections.Counter()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = getattr(func, "__name__", "")
        to_cpu = name == "to" and any(str(a).startswith("cpu") for a in (*args[1:], *kwargs.values()))
        if (name in READS or to_cpu) and args and isinstance(args[0], torch.Tensor):
            self.by_device[args[0].device.type] += 1
        return func(*args, **kwargs)


def reads_per_step(E: int, device: str, kind: str, steps: int = 6) -> list[collections.Counter]:
    """Host reads of each of ``steps`` training steps (act, store, update, advance) of an E-member ensemble."""
    agent = Agent(AgentConfig(kind=kind, **TINY), list(range(E)), device=device)
    loop = episode_loop(agent, VecEnv("changing_target", list(range(E))))
    active, episode = np.ones(E, dtype=bool), np.full(E, 5)  # past TINY's planning episodes: the kind's rule decides
    st = EpisodeState.fresh(E, agent.device)
    loop.start(st, active)
    out = []
    for _ in range(steps):
        with HostReads() as mode:
            info = loop.act(st, active, episode, explore=True)
            dev = agent.device
            agent.replay.add(torch.as_tensor(info.state, device=dev), torch.as_tensor(info.action, device=dev),
                             torch.as_tensor(info.reward, device=dev), torch.as_tensor(info.next_state, device=dev),
                             torch.as_tensor(info.terminal, dtype=torch.float32, device=dev), torch.as_tensor(active))
            losses = agent.update(torch.as_tensor(active))
            torch.stack(list(losses.values()), 1).cpu()  # the trainer's one transfer of the losses
            loop.advance(st, info, active)
        out.append(mode.by_device)
    return out


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("kind", ["apac", "ddpg"])
def test_host_reads_per_step_do_not_grow_with_the_ensemble(device, kind):
    small, large = reads_per_step(2, device, kind), reads_per_step(7, device, kind)
    assert small == large  # step by step, every device: nothing is read per member
    if device == "cuda":  # the action for MuJoCo, the step's record (StepInfo), the losses
        assert all(c["cuda"] <= 3 for c in large), large


def test_to_host_packs_device_tensors_and_keeps_values():
    g = torch.Generator().manual_seed(0)
    tensors = [torch.randn(3, 6, generator=g), torch.rand(3, generator=g) < 0.5, torch.randn(3, 2, 2, generator=g)]
    want = [t.float().numpy() for t in tensors]
    for device in DEVICES:
        got = to_host([t.to(device) for t in tensors])
        for w, h in zip(want, got):
            assert h.dtype == np.float32 and h.shape == w.shape and np.array_equal(h, w)
