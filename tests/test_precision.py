"""--precision auto: bf16 exactly where the hardware has bf16 dot products, said and recorded; a run keeps its own."""
from __future__ import annotations

import dataclasses
import json

import pytest

from apac_mj.agent import precision
from apac_mj.agent.precision import cpu_info, resolve
from apac_mj.run.trainer import train

from tests.test_trainer import tiny_config


def cpuinfo(model: str, flags: str) -> str:
    """/proc/cpuinfo of a two-core machine."""
    return "".join(f"processor\t: {i}\nmodel name\t: {model}\nflags\t\t: {flags}\n\n" for i in range(2))


BASE = "fpu sse sse2 avx avx2 fma"
ZEN4 = cpuinfo("AMD EPYC 9R14 96-Core Processor", BASE + " avx512f avx512bw avx512_bf16 avx512_vnni")
SAPPHIRE = cpuinfo("Intel(R) Xeon(R) Platinum 8488C", BASE + " avx512f avx512bw amx_bf16 amx_tile amx_int8")
ICELAKE = cpuinfo("Intel(R) Xeon(R) Platinum 8375C CPU", BASE + " avx512f avx512bw avx512_vnni")
ZEN2 = cpuinfo("AMD EPYC 7R32", BASE)


@pytest.mark.parametrize("text, want, flag", [(ZEN4, "bf16", "avx512_bf16"), (SAPPHIRE, "bf16", "amx_bf16"),
                                              (ICELAKE, "fp32", None), (ZEN2, "fp32", None)])
def test_auto_picks_bf16_only_with_bf16_dot_products(text, want, flag):
    cpu = cpu_info(text)
    assert cpu.model in text and cpu.flags["avx2"]
    got = resolve("auto", "cpu", cpu)
    assert got.precision == want
    assert cpu.model in got.reason
    if flag:  # the reason names what the CPU has ...
        assert flag in got.reason
    else:  # ... or what it lacks
        assert "lacks" in got.reason and "avx512_bf16" in got.reason and "amx_bf16" in got.reason


def test_explicit_precisions_are_kept_and_bad_ones_refused():
    for p in ("fp32", "bf16"):
        assert resolve(p, "cpu", cpu_info(ZEN2)).precision == p
        assert resolve(p, "cpu", cpu_info(ZEN4)).precision == p
    with pytest.raises(ValueError, match="precision must be one of"):
        resolve("fp16")


def test_cpu_info_without_proc_cpuinfo_has_no_flags():
    cpu = cpu_info("")
    assert not any(cpu.flags.values()) and not cpu.bf16_dot and cpu.model


def test_auto_run_records_the_resolved_choice_and_a_resumed_run_keeps_its_own(tmp_path, capsys, monkeypatch):
    cfg = dataclasses.replace(tiny_config((0,), episodes=1), precision="auto")
    here = resolve("auto").precision
    run = train(cfg, tmp_path / "run", progress=False)
    assert json.loads((run / "config.json").read_text())["precision"] == here
    assert f"precision {here}: auto: the CPU" in capsys.readouterr().err
    # the same run continued on a machine whose CPU resolves the other way keeps the run's precision
    other = cpu_info(ZEN2 if here == "bf16" else ZEN4)
    monkeypatch.setattr(precision, "cpu_info", lambda: other)
    assert resolve("auto").precision != here
    train(dataclasses.replace(cfg, episodes=2), run, progress=False)
    assert json.loads((run / "config.json").read_text())["precision"] == here
    assert "auto keeps the precision" in capsys.readouterr().err
