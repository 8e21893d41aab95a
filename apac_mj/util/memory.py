"""Out of memory, said as such: the address space a command needs, checked against the process's limit
(``ulimit -v``) before it starts, and a failed allocation named for what it is.

Below a command's need the native libraries fail in ways that name something else, or never return:
under ``ulimit -v 1000000`` (KB) dm_control said "Cannot initialize a headless EGL display"; under 1.5 GB
a resume hung in pyarrow (a reader thread that could not be started) and ``record`` hung importing scipy
(measured, issue 29 item 17). So a command is refused at its start, before it writes anything, when the
limit is below :data:`NEEDS`; above it, a :class:`MemoryError`, a library that cannot be mapped, or an
allocator's "can't allocate memory" becomes one message (:func:`out_of_memory`).
"""
from __future__ import annotations

import resource

GIB = 1 << 30
#: The address space (bytes) each command needs on the CPU, rounded up from the smallest ``ulimit -v`` under
#: which it ran (Linux x86-64, torch CPU build; issue 29 item 17): a resume ran at 1.6 GB and failed or hung
#: at 1.5 GB; evaluate ran at 1.5 GB; record, which renders with EGL and writes with Rerun's threads, ran at
#: 3.5 GB and failed or hung at 3.0 and 2.5 GB. A CUDA device maps far more than this.
NEEDS = {"train": 2 * GIB, "evaluate": 2 * GIB, "grid": 2 * GIB, "record": 4 * GIB, "demo": 4 * GIB}
#: What an allocation that failed says, in the libraries this project uses (lower case).
_SIGNS = ("can't allocate memory", "cannot allocate memory", "failed to map segment", "out of memory",
          "std::bad_alloc")


class OutOfMemory(MemoryError):
    """A command that cannot run in the memory it is given; the message names the command, the limit and the
    way out."""


def address_space_limit() -> int | None:
    """This process's address-space limit (``ulimit -v``, bytes); None: unlimited."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else int(soft)


def check_address_space(command: str, what: str) -> None:
    """Refuse ``command`` (``what``: its command line, for the message) at its start if the address-space limit
    is below its need (:data:`NEEDS`): an :class:`OutOfMemory` naming both."""
    need, limit = NEEDS.get(command), address_space_limit()
    if need is None or limit is None or limit >= need:
        return
    raise OutOfMemory(f"{what} needs about {need / GIB:.0f} GiB of address space (torch, MuJoCo's renderer and "
                      f"pyarrow map that much), and this process may use {_gib(limit)} (ulimit -v "
                      f"{limit // 1024}): raise the limit (ulimit -v unlimited, or at least {need // 1024}) and "
                      "run the same command again (nothing was started)")


def is_out_of_memory(e: BaseException) -> bool:
    """``e`` is a failed allocation: a MemoryError, or an ImportError, RuntimeError or OSError (ENOMEM) that says
    one."""
    return isinstance(e, MemoryError) or (isinstance(e, (ImportError, RuntimeError, OSError))
                                          and any(s in str(e).lower() for s in _SIGNS))


def out_of_memory(e: BaseException, what: str) -> str:
    """A failed allocation while running ``what`` (a command line) as one line: what ran out, the limit if there
    is one, the way out."""
    if isinstance(e, OutOfMemory):
        return str(e)
    limit = address_space_limit()
    where = (f"this process may use {_gib(limit)} of address space (ulimit -v {limit // 1024}): raise the limit"
             if limit is not None else "free some memory (or run fewer seeds or workers)")
    cause = (f"{type(e).__name__}: {e}" if str(e) else type(e).__name__).splitlines()[0][:200]
    return (f"out of memory while running {what} ({cause}); {where} and run the same command again: what was "
            "written is intact, and a run resumes from its last checkpoint")


def _gib(n: int) -> str:
    return f"{n / GIB:.2f} GiB"


# -- the planner's size: refused when made (apac_mj.config.TrainConfig), before anything runs -----------------------

#: Imagined steps per member and decision at most: (candidates + habit_candidates) x horizon x iterations of
#: ``agent.mpc`` (the default: (32 + 2) x 4 x 4 = 544). 100 000 cost 0.65 s of the dynamics model alone per
#: decision and member (200-200 model, one thread, the shared 2-core machine, measured): 20 s per 30-step episode.
MAX_IMAGINED_STEPS = 100_000
#: What the model alone took per decision at :data:`MAX_IMAGINED_STEPS` (s, measured as above).
IMAGINED_STEPS_SECONDS = 0.65
#: Floats per imagined sequence and step the planner holds at once, beside the networks' activations: the
#: sequence, its noise and the sample (3 x 2 actions), the hand (2) and the state (16 at most).
_FLOATS_PER_SEQUENCE_STEP = 3 * 2 + 2 + 16
#: The share of this machine's memory one run's planner may take.
PLANNER_MEMORY_SHARE = 0.5


def imagined_steps(mpc: object) -> int:
    """Imagined steps per member and decision of an ``agent.mpc`` table (:class:`apac_mj.rules.MPCParams`)."""
    return (mpc.candidates + mpc.habit_candidates) * mpc.horizon * mpc.iterations


def planner_bytes(agent: object, members: int) -> int:
    """Bytes the MPC planner of ``agent`` (an AgentConfig) holds at once for ``members`` seeds: every sampled
    sequence's steps, and the widest networks' activations for every sequence (the model's at each imagined
    step, the actor's and critic's at the horizon)."""
    mpc = agent.params["mpc"]
    sequences = members * (mpc.candidates + mpc.habit_candidates)
    widths = sum(mpc.model_hidden) * mpc.model_heads + sum(agent.actor_hidden) + sum(agent.critic_hidden)
    return 4 * sequences * (mpc.horizon * _FLOATS_PER_SEQUENCE_STEP + widths)


def physical_memory() -> int | None:
    """This machine's memory (bytes); None where the system does not say."""
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_planner(agent: object, members: int) -> None:
    """Refuse an ``agent.mpc`` table whose planning would take unreasonably long per decision
    (:data:`MAX_IMAGINED_STEPS`) or more than :data:`PLANNER_MEMORY_SHARE` of this machine's memory: a
    ValueError naming the settings, the limit and the way out (campaign 3's ``candidates=1e9`` reached 15.7 GB
    in 14 s; ``horizon=1e5`` finished no episode in 240 s)."""
    mpc = agent.params.get("mpc") if isinstance(agent.params, dict) else None
    if mpc is None:
        return
    steps = imagined_steps(mpc)
    if steps > MAX_IMAGINED_STEPS:
        raise ValueError(f"agent.mpc: (candidates {mpc.candidates} + habit_candidates {mpc.habit_candidates}) x "
                         f"horizon {mpc.horizon} x iterations {mpc.iterations} = {steps:,} imagined steps per "
                         f"decision; at most {MAX_IMAGINED_STEPS:,} (that many took {IMAGINED_STEPS_SECONDS} s of the "
                         "dynamics model alone per decision and seed, measured; the default is 544): lower them")
    need, have = planner_bytes(agent, members), physical_memory()
    if have is not None and need > PLANNER_MEMORY_SHARE * have:
        raise ValueError(f"agent.mpc: the planner would hold about {_gib(need)} at once ({members} seed(s) x "
                         f"(candidates {mpc.candidates} + habit_candidates {mpc.habit_candidates}) sequences of "
                         f"horizon {mpc.horizon}, model_hidden {list(mpc.model_hidden)}), more than "
                         f"{PLANNER_MEMORY_SHARE:.0%} of this machine's {_gib(have)}: lower candidates or "
                         "horizon, or run fewer seeds")
