"""The zoo: a finished run's networks shipped as safetensors, with a manifest and an environment contract.

A cell (``zoo/NAME/``, docs/zoo.md) holds ``networks.safetensors`` and ``manifest.json``:

* the tensors a frozen test reads (:data:`SHIPPED_NETWORKS`: actor, critic, their target networks (the
  arbitrator's delta reads ``Q'(s', pi'(s'))``), forward and inverse model, the dynamics model where the kind has
  one), in fp32 by default (fp16 halves the size but moved the shipped APAC's test numbers: docs/zoo.md); beside them the environments' state (link
  lengths, static targets, the targets' random streams) and the running statistics the tests start from. No
  optimizer, replay or noise state: a cell is for looking and testing, not for training on;
* the manifest: kind, task, seeds, episodes, the config, the package version and the run's commit, the numbers the
  shipped weights produce (written by ``apac-mj zoo export``), and the **environment contract**: the task after
  overrides, the observation and action specs, the control step, the plant and the motion function, each part
  with its own SHA-256 (:func:`contract`), so that a mismatch names the part that moved.

:func:`export` writes a cell from a finished run; :func:`read_cell` loads one (tensors only, no pickle; every
network tensor's shape and dtype checked against the kind's networks, a :class:`ZooError` naming the tensor
where they cannot fit; a contract part that changed since export is a warning naming it); :func:`materialize`
writes a cell as a run directory under the cache (:func:`cache_dir`), which ``evaluate``, ``record`` and
``forced-response test`` read as any run; :func:`resolve_run` is the one resolver the commands call.
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import math
import os
import platform
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from apac_mj.config import TrainConfig, train_config_from_dict
from apac_mj.kinematics import DEFAULT_ORIGIN, angle_grid, motion_function
from apac_mj.run import checkpoint
from apac_mj.run.build import environments, make_agent, task_record
from apac_mj.run.run_dir import (COMMIT, CONFIG, DONE, LATEST, NETWORK_KEYS, TASK_DIGEST, TASK_SPEC, RunDir,
                                 config_dict, diff, git_commit, say)
from apac_mj.suite import spec_for
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.suite.vec_env import VecEnv
from apac_mj.util import paths
from apac_mj.util.files import atomic_write_text, jsonable

if TYPE_CHECKING:
    import torch

MANIFEST, WEIGHTS = "manifest.json", "networks.safetensors"
#: A cell's weights are split into files of at most about this many bytes (one tensor larger than it gets a file
#: of its own): ``networks.safetensors`` (with the layout) and ``networks-1.safetensors``, ``networks-2...``, so
#: that no file a repository keeps is over 5 MB.
SHARD_BYTES = 4_000_000


def weight_files(cell: Path) -> list[Path]:
    """A cell's weight files in order: ``networks.safetensors``, then its shards ``networks-K.safetensors``."""
    rest = sorted(cell.glob("networks-*.safetensors"), key=lambda p: int(p.stem.rsplit("-", 1)[1]))
    return [cell / WEIGHTS, *rest]


def _shard(tensors: dict[str, "torch.Tensor"]) -> list[dict[str, "torch.Tensor"]]:
    """``tensors`` in order, packed into groups of at most :data:`SHARD_BYTES` (a larger tensor alone)."""
    groups: list[dict] = [{}]
    size = 0
    for name, t in tensors.items():
        n = t.numel() * t.element_size()
        if groups[-1] and size + n > SHARD_BYTES:
            groups.append({})
            size = 0
        groups[-1][name] = t
        size += n
    return groups
#: Bumped when a cell's layout changes.
ZOO_FORMAT = 1
#: The networks a cell ships, where the kind has them: every network the frozen tests read (the target actor and
#: critic too: the arbitrator's delta is ``r + gamma Q'(s', pi'(s')) - Q(s, a)``, Agent.td_error).
SHIPPED_NETWORKS = ("actor", "critic", "target_actor", "target_critic", "forward_model", "inverse_model",
                    "dynamics_model")
#: The environment contract's parts, each hashed on its own (:func:`contract`).
CONTRACT_PARTS = ("task", "plant", "observation_spec", "action_spec", "control_step", "motion_function")
DTYPES = {"fp16": "float16", "fp32": "float32"}
#: ``zoo:NAME`` names a cell of the checkout's zoo/ folder.
PREFIX = "zoo:"


class ZooError(ValueError):
    """A cell that cannot be written or loaded: the message names the file, the tensor or the part, and the way
    out. Nothing was written."""


@dataclasses.dataclass
class Cell:
    """A loaded cell (:func:`read_cell`)."""

    path: Path
    manifest: dict[str, Any]
    cfg: TrainConfig
    spec: TaskSpec
    env: VecEnv
    #: Each shipped network's tensors, in fp32 (``{"actor": {"0.weight": ...}}``).
    networks: dict[str, dict[str, torch.Tensor]]
    #: The rest of the shipped state: ``{"env": ..., "running": ...}``.
    state: dict[str, Any]
    #: The contract parts that differ from the manifest's, each with what changed (empty: none).
    changed: dict[str, list[str]]


# -- the environment contract ------------------------------------------------------------------------------
def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, allow_nan=True).encode()).hexdigest()


def _array_spec(spec: Any) -> dict[str, Any]:
    """A dm_env array spec as JSON: name, shape, dtype, bounds and scale where it has them."""
    out = {"name": spec.name, "shape": list(spec.shape), "dtype": str(np.dtype(spec.dtype))}
    for key in ("minimum", "maximum", "scale"):
        if hasattr(spec, key):
            out[key] = jsonable(np.asarray(getattr(spec, key)).tolist())
    return out


def _motion_probe() -> dict[str, Any]:
    """The motion function (Algorithm 1) on a probe: the 10 x 10 angle grid at two pairs of link lengths; the end
    and elbow positions rounded to 1e-9 cm (so that the last bit of a cosine does not count) and hashed."""
    grid = angle_grid(10)
    probes = [motion_function(grid[:, 0], grid[:, 1], l1, l2) for l1, l2 in ((5.0, 8.0), (6.0, 9.5))]
    values = np.round(np.stack([np.stack(p) for p in probes]), 9) + 0.0  # + 0.0: no negative zero
    return {"origin": list(DEFAULT_ORIGIN), "probe": "angle_grid(10) at lengths (5, 8) and (6, 9.5)",
            "first_end": values[0, 0, 0].tolist(), "positions_sha256": hashlib.sha256(values.tobytes()).hexdigest()}


def contract(cfg: TrainConfig, spec: TaskSpec, env: VecEnv) -> dict[str, dict[str, Any]]:
    """The environment contract of ``cfg``'s task as this code builds it: ``{part: {"sha256", "value"}}`` for
    every part of :data:`CONTRACT_PARTS` (``env``: the run's environments)."""
    record = task_record(cfg, spec).spec
    arm = env.envs[0]
    step, dt = float(arm.control_timestep()), float(arm.physics.model.opt.timestep)
    parts = {
        "task": {k: v for k, v in record.items() if k != "plant"},
        "plant": {"spec": record.get("plant"), "actuation": cfg.actuation,
                  "model_xml_sha256": hashlib.sha256(paths.arm_xml_path().read_bytes()).hexdigest()},
        "observation_spec": {k: _array_spec(v) for k, v in arm.observation_spec().items()},
        "action_spec": _array_spec(arm.action_spec()),
        "control_step": {"control_timestep_s": step, "physics_timestep_s": dt, "sub_steps": int(round(step / dt)),
                         "steps_per_episode": spec.steps_per_episode},
        "motion_function": _motion_probe(),
    }
    return {name: {"sha256": _digest(value), "value": value} for name, value in parts.items()}


def contract_changes(shipped: dict[str, Any], now: dict[str, Any]) -> dict[str, list[str]]:
    """The contract parts whose hash differs between ``shipped`` (a manifest's) and ``now``, each with the fields
    that changed (a part missing on either side: said so)."""
    out = {}
    for part in CONTRACT_PARTS:
        a, b = shipped.get(part), now.get(part)
        if a is None or b is None:
            out[part] = ["missing " + ("in the cell" if a is None else "in this code")]
        elif a["sha256"] != b["sha256"]:
            old, new = a.get("value"), b.get("value")
            fields = diff(old, new, "shipped") if isinstance(old, dict) and isinstance(new, dict) else []
            out[part] = fields or [f"{old!r} shipped, {new!r} now"]
    return out


# -- tensors <-> safetensors ------------------------------------------------------------------------------
def _flatten(obj: Any, key: str, tensors: dict[str, torch.Tensor]) -> Any:
    """``obj`` (nested dicts and lists of tensors and plain values) as JSON, each tensor replaced by its key in
    ``tensors``."""
    import torch

    if isinstance(obj, torch.Tensor):
        tensors[key] = obj.detach().cpu().clone().contiguous()
        return {"tensor": key}
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise ZooError(f"{key}: only string keys can be shipped, got {sorted(map(repr, obj))}")
        return {"dict": {k: _flatten(v, f"{key}/{k}", tensors) for k, v in obj.items()}}
    if isinstance(obj, (list, tuple)):
        return {"list": [_flatten(v, f"{key}/{i}", tensors) for i, v in enumerate(obj)]}
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return {"value": obj}
    raise ZooError(f"{key}: a {type(obj).__name__} cannot be shipped (tensors, numbers, strings, lists, dicts)")


def _unflatten(node: dict[str, Any], tensors: dict[str, torch.Tensor], where: Path) -> Any:
    """The inverse of :func:`_flatten`; a tensor the file lacks is a :class:`ZooError` naming it."""
    if "tensor" in node:
        if node["tensor"] not in tensors:
            raise ZooError(f"{where} lacks the tensor {node['tensor']!r} its layout names: the file is damaged; "
                           "export the cell again")
        return tensors[node["tensor"]]
    if "dict" in node:
        return {k: _unflatten(v, tensors, where) for k, v in node["dict"].items()}
    if "list" in node:
        return [_unflatten(v, tensors, where) for v in node["list"]]
    return node["value"]


def shipped_networks(names: tuple[str, ...]) -> list[str]:
    """The networks of an agent (``names``: its ``networks``) a cell ships; one this module does not know is an
    error (a new network must be added to :data:`SHIPPED_NETWORKS` or left out on purpose)."""
    unknown = [n for n in names if n not in SHIPPED_NETWORKS]
    if unknown:
        raise ZooError(f"the agent has network(s) {unknown} the zoo does not know: add them to "
                       "apac_mj.run.zoo.SHIPPED_NETWORKS")
    return list(names)


def _network_tensors(agent_state: dict[str, Any], names: list[str], dtype: str) -> dict[str, torch.Tensor]:
    """The shipped networks' tensors (``networks/NAME/PARAM``), floats cast to ``dtype``; a value past fp16's range
    is an error naming it."""
    import torch

    out, target = {}, getattr(torch, DTYPES[dtype])
    for n in names:
        for k, v in agent_state["networks"][n].items():
            if v.is_floating_point() and dtype == "fp16" and bool((v.abs() > torch.finfo(torch.float16).max).any()):
                raise ZooError(f"{n}.{k} holds values beyond float16's range ({float(v.abs().max()):.3g}): export "
                               "with --dtype fp32")
            out[f"networks/{n}/{k}"] = (v.to(target) if v.is_floating_point() else v).detach().cpu().contiguous()
    return out


# -- writing a cell ----------------------------------------------------------------------------------------
def package_version() -> str:
    try:
        return importlib.metadata.version("apac_mj")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def export(run_dir: str | Path, out: str | Path, dtype: str = "fp16") -> Path:
    """Write a cell (``out``: a new directory) from the finished run ``run_dir``: its final checkpoint's shipped
    networks in ``dtype`` ("fp16" or "fp32"), the environments' state, the running statistics and the manifest
    (without published numbers: ``apac-mj zoo export`` adds them). Everything is checked before ``out`` is made."""
    if dtype not in DTYPES:
        raise ZooError(f"dtype must be one of {sorted(DTYPES)}, got {dtype!r}")
    out, run = Path(out), RunDir(run_dir)
    if out.exists() and any(out.iterdir()):
        raise ZooError(f"{out} exists and is not empty: remove it, or export into another --out")
    if (problem := run.problem()) is not None:
        raise FileNotFoundError(problem)
    if not run.check_finished():
        raise ZooError(f"{run.path} has not finished training (no DONE): run its apac-mj train command to the end "
                       "first; a cell ships a finished run's networks")
    ckpt = run.load_checkpoint(required=NETWORK_KEYS)
    run.check_config(ckpt)
    cfg = run.train_config()
    spec = spec_for(cfg)
    run.check_task(task_record(cfg, spec), "the cell's contract would describe another task than it trained")
    env = environments(cfg, spec)
    names = shipped_networks(tuple(ckpt.agent["networks"]))
    tensors = _network_tensors(ckpt.agent, names, dtype)
    layout = {"env": _flatten(ckpt.env, "env", tensors),
              "running": _flatten(ckpt.running_statistics(), "running", tensors)}
    manifest = _manifest(run, cfg, spec, ckpt, env, names, tensors, dtype)
    _write_cell(out, tensors, layout, manifest)
    return out


def _manifest(run: RunDir, cfg: TrainConfig, spec: TaskSpec, ckpt: Any, env: VecEnv, names: list[str],
              tensors: dict[str, torch.Tensor], dtype: str) -> dict[str, Any]:
    """A new cell's manifest (``published`` and ``regression`` are filled in by ``apac-mj zoo export``)."""
    stored = json.loads((run.path / CONFIG).read_text())
    return {"zoo_format": ZOO_FORMAT, "kind": cfg.agent.kind, "task": cfg.task, "seeds": list(cfg.seeds),
            "episodes": cfg.episodes,
            "network_episodes": [ckpt.member_episode(k) for k in range(len(cfg.seeds))],
            "precision_trained": cfg.precision, "dtype": DTYPES[dtype],
            "package_version": package_version(), "commit": stored.get(COMMIT, "unknown"),
            "exported_at_commit": git_commit(), "source_run": run.path.name,
            "networks": {n: {k.split("/", 2)[2]: list(t.shape) for k, t in tensors.items()
                             if k.startswith(f"networks/{n}/")} for n in names},
            "config": config_dict(cfg), "contract": contract(cfg, spec, env),
            "published": {}, "regression": {}}


def _write_cell(out: Path, tensors: dict[str, torch.Tensor], layout: dict[str, Any], manifest: dict[str, Any]) -> None:
    """Write the cell's two files into a temporary directory beside ``out``, then move it into place."""
    from safetensors.torch import save_file

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        for i, group in enumerate(_shard(tensors)):
            meta = {"apac_mj_zoo": str(ZOO_FORMAT), **({"layout": json.dumps(layout)} if i == 0 else {})}
            save_file(group, str(tmp / (WEIGHTS if i == 0 else f"networks-{i}.safetensors")), metadata=meta)
        atomic_write_text(tmp / MANIFEST, json.dumps(manifest, indent=1, allow_nan=True) + "\n")
        for f in tmp.iterdir():
            f.chmod(0o644)
        tmp.chmod(0o755)
        if out.exists():
            out.rmdir()  # empty (checked above)
        os.replace(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def update_manifest(cell_dir: str | Path, **fields: Any) -> dict[str, Any]:
    """Set ``fields`` of a cell's manifest (atomically); return it."""
    path = Path(cell_dir) / MANIFEST
    manifest = read_manifest(cell_dir)
    manifest.update(fields)
    atomic_write_text(path, json.dumps(manifest, indent=1, allow_nan=True) + "\n")
    return manifest


# -- reading a cell ----------------------------------------------------------------------------------------
def zoo_dir() -> Path:
    """The checkout's zoo/ folder (``zoo:NAME`` names a cell in it)."""
    return paths.repo_root() / "zoo"


def is_cell(path: str | Path) -> bool:
    """``path`` is a cell directory (its manifest is there)."""
    return (Path(path) / MANIFEST).is_file()


def cell_path(spec: str | Path) -> Path:
    """The cell ``spec`` names: ``zoo:NAME`` (in :func:`zoo_dir`) or a directory; an unknown one is an error
    listing the cells there are."""
    text = str(spec)
    path = zoo_dir() / text[len(PREFIX):] if text.startswith(PREFIX) else Path(spec)
    if not is_cell(path):
        known = ", ".join(PREFIX + p.name for p in list_cells()) or "none"
        raise FileNotFoundError(f"{spec} is not a zoo cell (no {path / MANIFEST}); the cells in zoo/: {known}")
    return path


def list_cells(root: str | Path | None = None) -> list[Path]:
    """The cells under ``root`` (default :func:`zoo_dir`), by name."""
    root = zoo_dir() if root is None else Path(root)
    return sorted(p.parent for p in root.glob(f"*/{MANIFEST}")) if root.is_dir() else []


def read_manifest(cell_dir: str | Path) -> dict[str, Any]:
    """A cell's manifest; a damaged or foreign one is a :class:`ZooError` naming the file."""
    path = Path(cell_dir) / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ZooError(f"{path} cannot be read ({type(e).__name__}: {e}): export the cell again") from None
    if not isinstance(manifest, dict) or manifest.get("zoo_format") != ZOO_FORMAT:
        raise ZooError(f"{path} is not a zoo manifest of format {ZOO_FORMAT} (it says "
                       f"{manifest.get('zoo_format') if isinstance(manifest, dict) else manifest!r}): export the "
                       "cell again with this code")
    return manifest


def _read_tensors(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The tensors and the layout of a cell's safetensors file ``path`` and its shards (tensors only: no code is
    read)."""
    from safetensors import safe_open

    try:
        tensors = {}
        for i, file in enumerate(weight_files(path.parent)):
            with safe_open(str(file), framework="pt") as f:
                if i == 0:
                    layout = json.loads((f.metadata() or {})["layout"])
                tensors.update({k: f.get_tensor(k) for k in f.keys()})
    except Exception as e:  # noqa: BLE001 - safetensors raises several types for bad bytes
        raise ZooError(f"{path} is damaged or not a zoo cell's weights ({type(e).__name__}: {e}): export the cell "
                       "again") from None
    return tensors, layout


def read_cell(cell_dir: str | Path) -> Cell:
    """Load a cell and check it against this code: the contract part by part (a changed part is said as a
    warning naming it), then every shipped network's tensors against the kind's networks (names, shapes,
    dtypes: a :class:`ZooError` naming the tensor, and the changed parts, where they cannot fit)."""
    path = Path(cell_dir)
    manifest = read_manifest(path)
    tensors, layout = _read_tensors(path / WEIGHTS)
    cfg = train_config_from_dict(manifest["config"])
    spec = spec_for(cfg)
    env = environments(cfg, spec)
    changed = contract_changes(manifest.get("contract", {}), contract(cfg, spec, env))
    for part, fields in changed.items():
        say(f"warning: zoo cell {path.name}: the environment contract's part {part!r} changed since the cell was "
            f"exported ({'; '.join(fields)[:400]}): its numbers may no longer be reproduced")
    expected = make_agent(cfg, spec, env.sizes, device="cpu", precision="fp32").state_dict()["networks"]
    networks = _checked_networks(path / WEIGHTS, manifest, tensors, expected, changed)
    state = {k: _unflatten(v, tensors, path / WEIGHTS) for k, v in layout.items()}
    return Cell(path, manifest, cfg, spec, env, networks, state, changed)


def _checked_networks(where: Path, manifest: dict[str, Any], tensors: dict[str, torch.Tensor],
                      expected: dict[str, dict[str, torch.Tensor]],
                      changed: dict[str, list[str]]) -> dict[str, dict[str, torch.Tensor]]:
    """The shipped networks in fp32, each tensor checked against the kind's network (``expected``)."""
    import torch

    because = f" (the contract's {', '.join(changed)} changed since export)" if changed else ""
    dtype = getattr(torch, manifest["dtype"])
    out: dict[str, dict[str, torch.Tensor]] = {}
    for n in manifest["networks"]:
        if n not in expected:
            raise ZooError(f"{where}: the cell ships a {n!r} that a {manifest['kind']!r} agent does not have{because}")
        shipped = {k.split("/", 2)[2]: t for k, t in tensors.items() if k.startswith(f"networks/{n}/")}
        if set(shipped) != set(expected[n]):
            raise ZooError(f"{where}: {n} ships {sorted(shipped)}, the kind's network has {sorted(expected[n])}"
                           f"{because}; export the cell again from a run of this code")
        for k, t in shipped.items():
            want = expected[n][k]
            if tuple(t.shape) != tuple(want.shape):
                raise ZooError(f"{where}: {n}.{k} has shape {tuple(t.shape)}, this code's {manifest['kind']} network "
                               f"needs {tuple(want.shape)}{because}: the weights cannot be loaded")
            if t.is_floating_point() and t.dtype != dtype:
                raise ZooError(f"{where}: {n}.{k} is {t.dtype}, the manifest says {manifest['dtype']}: the file "
                               "was replaced or damaged; export the cell again")
        out[n] = {k: t.to(want.dtype) for k, t in shipped.items() for want in [expected[n][k]]}
    missing = [n for n in SHIPPED_NETWORKS if n in expected and n not in out]
    if missing:
        raise ZooError(f"{where}: the cell lacks the network(s) {missing} a {manifest['kind']!r} agent acts with"
                       f"{because}")
    return out


# -- a cell as a run directory -----------------------------------------------------------------------------
def cache_dir() -> Path:
    """Where cells are materialized as run directories: ``$APAC_MJ_ZOO_CACHE``, else
    ``$XDG_CACHE_HOME/apac_mj/zoo`` (``~/.cache/apac_mj/zoo``)."""
    if os.environ.get("APAC_MJ_ZOO_CACHE"):
        return Path(os.environ["APAC_MJ_ZOO_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "apac_mj" / "zoo"


#: Manifest fields that say what a cell's weights produce, not what they are: not in the cache key.
_SCORES = ("published", "regression", "fp32_run")


def _cache_key(path: Path, manifest: dict[str, Any]) -> str:
    """A digest of the cell's weights, its manifest (without its scores) and this code's commit: a re-exported
    cell or other code, another copy."""
    h = hashlib.sha256(b"".join(hashlib.sha256(f.read_bytes()).digest() for f in weight_files(path)))
    h.update(json.dumps({k: v for k, v in manifest.items() if k not in _SCORES}, sort_keys=True).encode())
    h.update(git_commit().encode())
    return h.hexdigest()[:16]


def materialize(cell_dir: str | Path, cache: str | Path | None = None) -> Path:
    """The cell as a finished run directory (config.json, checkpoints/latest.pt, DONE) under ``cache`` (default
    :func:`cache_dir`), made once per cell, code and contract (:func:`read_cell` checks it every time)."""
    cell = read_cell(cell_dir)
    root = cache_dir() if cache is None else Path(cache)
    key = hashlib.sha256((_cache_key(cell.path, cell.manifest) + json.dumps(sorted(cell.changed))).encode()
                         ).hexdigest()[:16]
    out = root / f"{cell.path.name}-{key}"
    if (out / DONE).is_file():
        return out
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=root))
    try:
        _write_run(cell, tmp)
        if not (out / DONE).is_file():
            shutil.rmtree(out, ignore_errors=True)
            os.replace(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def _write_run(cell: Cell, out: Path) -> None:
    """Write ``cell`` as a finished run into ``out``: the kind's agent with the shipped networks (the optimizer,
    replay and noise fresh: the tests do not read them), on the CPU whatever device it trained on (``--device``
    moves it)."""
    import torch

    cfg = dataclasses.replace(cell.cfg, device="cpu")
    agent = make_agent(cfg, cell.spec, cell.env.sizes, device="cpu", precision="fp32")
    state = agent.state_dict()
    for n in state["networks"]:
        state["networks"][n] = {k: v.clone() for k, v in cell.networks[n].items()}
    config = config_dict(cfg)
    record = task_record(cfg, cell.spec)
    atomic_write_text(out / CONFIG, json.dumps({**config, COMMIT: cell.manifest.get("commit", "unknown"),
                                                TASK_SPEC: record.spec, TASK_DIGEST: record.digest}, indent=2) + "\n")
    episodes = torch.tensor(cell.manifest["network_episodes"])
    checkpoint.save({"config": config, "loop": {"episode": episodes}, "agent": state, "env": cell.state["env"],
                     **cell.state["running"], "babbling_generators": [], "metric_rows": 0},
                    out / "checkpoints" / LATEST)
    RunDir(out).mark_finished()


def resolve_run(spec: str | Path) -> Path:
    """The run directory a command reads for ``spec``: a zoo cell (``zoo:NAME`` or a cell directory) materialized
    (:func:`materialize`), said on stderr; anything else as it is."""
    text = str(spec)
    if not text.startswith(PREFIX) and not is_cell(spec):
        return Path(spec)
    run = materialize(cell_path(spec))
    say(f"zoo cell {text}: its networks, as a run, in {run}")
    return run


# -- the regression check ----------------------------------------------------------------------------------
#: The columns of a regression episode (the grid protocol's, without the measured wall times).
REGRESSION_COLUMNS = ("seed", "target_index", "success", "steps", "final_distance", "habit_actions",
                      "planning_actions")


def regression_rows(run_dir: str | Path, targets: int) -> list[dict[str, Any]]:
    """The frozen grid episodes of a run's first ``targets`` targets per seed, exactly (:data:`REGRESSION_COLUMNS`):
    what a cell's manifest stores and :func:`check_regression` compares."""
    import pandas as pd

    from apac_mj.run.evaluate import evaluate

    evaluate(run_dir, protocols=("grid",), limit=targets, threads=1)
    df = pd.read_parquet(RunDir(run_dir).eval_path("grid"))[list(REGRESSION_COLUMNS)]
    return [{k: (v.item() if isinstance(v, np.generic) else v) for k, v in r.items()} for r in df.to_dict("records")]


def store_regression(cell_dir: str | Path, targets: int, cache: str | Path | None = None) -> dict[str, Any]:
    """Run a cell's first ``targets`` grid targets per seed from its shipped weights and store the episodes in its
    manifest (``regression``, with this machine's type) for :func:`check_regression`; return the block."""
    run = materialize(cell_dir, cache)
    block = {"protocol": "grid", "targets_per_seed": targets, "rows": regression_rows(run, targets),
             "machine": machine()}
    update_manifest(cell_dir, regression=block)
    return block


def machine() -> str:
    """The machine type identical numbers are promised on: architecture, CPU model, torch."""
    import torch

    model = platform.processor() or platform.machine()
    try:
        model = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                     if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{platform.machine()} ({model}), torch {torch.__version__}"


#: Relative tolerance of a regression episode's float columns on another machine type than the one that stored
#: it (other CPUs round matrix products differently: an AVX-512 Xeon with AMX gave relative differences up to 1e-7
#: in returns and distances against an AVX2 fixture, tests/test_old_runs.py, which allows 1e-5 as here); integer and
#: boolean columns stay exact, and on the same machine type every value must be identical.
OTHER_MACHINE_RTOL = 1e-5


def _same_row(a: dict[str, Any], b: dict[str, Any], exact: bool) -> bool:
    if exact or a.keys() != b.keys():
        return a == b
    return all(math.isclose(x, b[k], rel_tol=OTHER_MACHINE_RTOL, abs_tol=1e-9) if isinstance(x, float) else
               x == b[k] for k, x in a.items())


def check_regression(cell_dir: str | Path, cache: str | Path | None = None) -> None:
    """Re-run a cell's stored regression episodes from its shipped weights: identical on the machine type that
    stored them, within :data:`OTHER_MACHINE_RTOL` on another. A difference is a :class:`ZooError` naming the first
    episode that moved and the contract parts that changed (none: the agent's inference path or the code under it
    changed)."""
    path = cell_path(cell_dir)
    stored = read_manifest(path).get("regression") or {}
    if not stored.get("rows"):
        raise ZooError(f"{path / MANIFEST} stores no regression episodes: export the cell with apac-mj zoo export")
    run = materialize(path, cache)
    now = regression_rows(run, int(stored["targets_per_seed"]))
    exact = stored.get("machine") in (None, machine())
    moved = [(a, b) for a, b in zip(stored["rows"], now) if not _same_row(a, b, exact)]
    if not moved and len(now) == len(stored["rows"]):
        return
    changed = read_cell(path).changed
    first = f"first: {moved[0][0]} shipped, {moved[0][1]} now" if moved else f"{len(stored['rows'])} rows shipped, " \
                                                                              f"{len(now)} now"
    why = ("the environment contract's " + "; ".join(f"{p} changed ({'; '.join(f)[:300]})" for p, f in changed.items())
           if changed else "no contract part changed: the agent's inference path or the code under it changed")
    raise ZooError(f"zoo cell {path.name}: {len(moved)} of {len(stored['rows'])} regression episodes differ ({first}); "
                   f"{why}")
