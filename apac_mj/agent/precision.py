"""Which precision the update runs in: ``fp32``, ``bf16``, or ``auto`` resolved from the hardware.

``bf16`` (autocast of the matrix products) pays only where the hardware has
bf16 dot products: on a CPU the ``avx512_bf16`` (AVX512-BF16: Zen 4, Cooper
Lake and later Xeons) or ``amx_bf16`` (AMX: Sapphire Rapids and later) flags in
``/proc/cpuinfo``, on a GPU CUDA's bf16 support (Ampere and later). Without
them oneDNN emulates bf16 through fp32 FMA plus conversions, which is slower
than fp32 (measured in docs/agent.md, "Speed"). ``auto`` picks ``bf16`` where
the hardware has them and ``fp32`` elsewhere, and says why; a run records the
resolved choice in config.json (``precision``), never ``auto``.

bf16 changes the numbers (not bit-reproducible against fp32; docs/agent.md);
fp32 stays the default.
"""
from __future__ import annotations

import contextlib
import dataclasses
import platform
from pathlib import Path

from apac_mj.config import PRECISION_REQUESTS

#: What a run may ask for; ``auto`` is resolved by :func:`resolve` before the run starts.
REQUESTS = PRECISION_REQUESTS
#: The CPU flags (``/proc/cpuinfo``) that give bf16 dot products.
BF16_CPU_FLAGS = ("avx512_bf16", "amx_bf16")


@dataclasses.dataclass(frozen=True)
class CpuInfo:
    """The CPU as the precision choice sees it."""

    #: ``model name`` in /proc/cpuinfo (or platform.processor()).
    model: str
    #: The flags that matter here, each present or not: avx2, avx512f, avx512_bf16, amx_bf16, amx_tile.
    flags: dict[str, bool]

    @property
    def bf16_dot(self) -> bool:
        """The CPU has bf16 dot-product instructions (AVX512-BF16 or AMX-BF16)."""
        return any(self.flags.get(f, False) for f in BF16_CPU_FLAGS)

    def describe(self) -> str:
        have = [f for f, on in self.flags.items() if on]
        lack = [f for f, on in self.flags.items() if not on]
        return f"{self.model} (has {', '.join(have) or 'none'}; lacks {', '.join(lack) or 'none'})"


#: The flags :class:`CpuInfo` reports.
REPORTED_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_tile", "amx_bf16")


def cpu_info(cpuinfo: str | None = None) -> CpuInfo:
    """The CPU's model and bf16-relevant flags, from ``cpuinfo`` (the text of /proc/cpuinfo; default: read it).
    Where /proc/cpuinfo does not exist (not Linux), every flag reads as absent."""
    if cpuinfo is None:
        path = Path("/proc/cpuinfo")
        cpuinfo = path.read_text() if path.exists() else ""
    model, flags = None, None
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name" and model is None:
            model = value.strip()
        elif key.strip() == "flags" and flags is None:
            flags = set(value.split())
    return CpuInfo(model=model or platform.processor() or "unknown CPU",
                   flags={f: f in (flags or set()) for f in REPORTED_FLAGS})


@dataclasses.dataclass(frozen=True)
class Resolved:
    """A precision choice and the reason for it (what the run says and config.json records)."""

    precision: str
    reason: str


def resolve(requested: str, device: str = "cpu", cpu: CpuInfo | None = None) -> Resolved:
    """``requested`` (``fp32``, ``bf16`` or ``auto``) on ``device`` -> the precision to run and why.

    ``auto``: bf16 on a CUDA device that supports it (``torch.cuda.is_bf16_supported()``) or on a CPU with
    bf16 dot products (:data:`BF16_CPU_FLAGS`), else fp32. An explicit ``fp32``/``bf16`` is kept as asked."""
    if requested not in REQUESTS:
        raise ValueError(f"precision must be one of {REQUESTS}, got {requested!r}")
    if requested != "auto":
        return Resolved(requested, f"{requested} as requested")
    if str(device).startswith("cuda"):
        import torch

        if torch.cuda.is_available() and torch.cuda.is_bf16_supported():
            name = torch.cuda.get_device_name(torch.device(device))
            return Resolved("bf16", f"auto: {name} supports bf16")
        return Resolved("fp32", f"auto: CUDA device {device} without bf16 support")
    cpu = cpu or cpu_info()
    if cpu.bf16_dot:
        which = [f for f in BF16_CPU_FLAGS if cpu.flags.get(f)]
        return Resolved("bf16", f"auto: the CPU {cpu.model} has bf16 dot products ({', '.join(which)})")
    return Resolved("fp32", f"auto: the CPU {cpu.model} lacks bf16 dot products (no {' or '.join(BF16_CPU_FLAGS)} "
                            "in /proc/cpuinfo), so bf16 would be emulated and slower than fp32")


def autocast(device_type: str, precision: str) -> "contextlib.AbstractContextManager":
    """The update's autocast: the matrix products in bf16 where ``precision`` is ``bf16``; else nothing."""
    import torch

    if precision == "bf16":
        return torch.autocast(device_type, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def fp32_unless(net: str, device_type: str, precision: str,
                networks: tuple[str, ...]) -> "contextlib.AbstractContextManager":
    """Inside the update's autocast: fp32 for ``net`` (a target network counts as its online one) when the update
    runs in bf16 but ``networks`` (``AgentConfig.bf16_networks``) leaves it out; else no change."""
    import torch

    if precision == "bf16" and net not in networks:
        return torch.autocast(device_type, enabled=False)
    return contextlib.nullcontext()
