"""The import graph of apac_mj (read with ast, function-local imports included): acyclic, and in layer order.

The layers, lowest first (docs/architecture.md): the vocabulary and helpers; the plant (``suite``) and the
learner (``agent``), which never import each other; one run (``run``); recordings and the experiment grid;
the report; the demo; the command line. A module imports only from its own layer or below.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "apac_mj"


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in PACKAGE.rglob("*.py")}


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    """Nodes under ``if TYPE_CHECKING:`` (annotations only, never executed)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING":
            out |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return out


def imports(name: str, type_level: bool = False) -> set[str]:
    """The apac_mj modules ``name`` imports, anywhere in the file (also inside functions); with
    ``type_level`` also those imported for annotations only (under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(MODULES[name].read_text())
    skip, out = set() if type_level else _type_checking_nodes(tree), set()
    package = name if MODULES[name].name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            out |= {f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names}
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "import_module" and node.args \
                and isinstance(node.args[0], ast.Constant):
            out.add(node.args[0].value)
    return {m for m in out if m in MODULES and m != name}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a path ``[a, b, ..., a]``, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (cycle := visit(m)):
                return cycle
        state[n] = 2
        stack.pop()
        return None

    for n in sorted(graph):
        if n not in state and (cycle := visit(n)):
            return cycle
    return None


def test_the_import_graph_is_acyclic():
    graph = {name: imports(name) for name in MODULES}
    assert sum(map(len, graph.values())) > 50  # the graph was read
    assert "apac_mj.experiments.grid" in graph["apac_mj.commands.grid"] or "apac_mj.experiments.grid" in graph["apac_mj.demo"]
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_cycles():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_library_modules_do_not_import_the_command_line():
    graph = {name: imports(name) for name in MODULES}
    upward = sorted(f"{n} -> {m}" for n, ms in graph.items() if not n.startswith("apac_mj.commands")
                    and n != "apac_mj.cli" for m in ms if m.startswith("apac_mj.commands") or m == "apac_mj.cli")
    assert not upward, upward
    assert not any(m == "apac_mj.cli" for m in graph["apac_mj.commands.demo"])


def test_no_cycle_at_type_level():
    """Imports for annotations only count too: no loop even a type checker has to break."""
    graph = {name: imports(name, type_level=True) - {"apac_mj"} for name in MODULES}
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle at type level: " + " -> ".join(cycle)


#: Layers, lowest first: (rank, module-name prefixes). A prefix ending in "." names a package's modules.
LAYERS = (
    (0, ("apac_mj.util", "apac_mj.types", "apac_mj.layout", "apac_mj.kinematics", "apac_mj.config", "apac_mj.kinds",
         "apac_mj.rules", "apac_mj.systems")),
    (1, ("apac_mj.suite", "apac_mj.agent")),
    (2, ("apac_mj.run",)),
    (3, ("apac_mj.recording", "apac_mj.experiments")),
    (4, ("apac_mj.report",)),
    (5, ("apac_mj.demo",)),
    (6, ("apac_mj.cli", "apac_mj.commands")),
    (7, ("apac_mj",)),  # the package's face: loads the rest lazily, by name
)
#: Edges against the order, each with its reason. The registries (vocabulary) name their built-in arbitration
#: rules, planners and integrators, imported when one is first built, so that ``kinds`` and ``systems`` stay
#: torch-free.
DECLARED_UPWARD = {
    ("apac_mj.kinds", "apac_mj.agent.arbitration"): "built-in kinds' rules, imported on first use",
    ("apac_mj.kinds", "apac_mj.agent.arbitrators"): "built-in kinds' rules, imported on first use",
    ("apac_mj.systems", "apac_mj.agent.planner"): "built-in planners, imported on first use",
    ("apac_mj.systems", "apac_mj.agent.integrator"): "built-in integrators, imported on first use",
}


def layer(name: str) -> int:
    """The rank of module ``name`` (the most specific matching prefix)."""
    matches = [(len(p), rank) for rank, prefixes in LAYERS for p in prefixes if name == p.rstrip(".")
               or name.startswith(p if p.endswith(".") else p + ".")]
    assert matches, f"{name} is in no layer: add it to LAYERS (and docs/architecture.md)"
    return max(matches)[1]


def test_every_module_has_a_layer_and_imports_only_downward():
    graph = {name: imports(name) for name in MODULES}
    upward = sorted(f"{n} (layer {layer(n)}) -> {m} (layer {layer(m)})" for n, ms in graph.items() for m in ms
                    if layer(m) > layer(n) and (n, m) not in DECLARED_UPWARD)
    assert not upward, "imports against the layer order:\n" + "\n".join(upward)


def test_the_plant_and_the_learner_never_import_each_other():
    graph = {name: imports(name, type_level=True) for name in MODULES}
    for a, b in (("apac_mj.suite", "apac_mj.agent"), ("apac_mj.agent", "apac_mj.suite")):
        crossing = sorted(f"{n} -> {m}" for n, ms in graph.items() for m in ms
                          if (n == a or n.startswith(a + ".")) and (m == b or m.startswith(b + ".")))
        assert not crossing, crossing


def test_the_layer_check_sees_a_violation():
    assert layer("apac_mj.agent.agent") == 1 and layer("apac_mj.run.trainer") == 2 and layer("apac_mj") == 7
    assert layer("apac_mj.util.files") == 0 and layer("apac_mj.report") == 4 and layer("apac_mj.commands.grid") == 6
    graph = {name: imports(name) for name in MODULES}
    assert "apac_mj.agent.agent" in graph["apac_mj.run.build"]  # a real downward edge, read from the file
    with pytest.raises(AssertionError):
        layer("apac_mjx.other")


def test_the_top_level_is_the_vocabulary_and_the_face():
    """At most 10 modules directly in apac_mj/: the face (``__init__``, ``cli``, ``demo``) and the torch-free
    vocabulary (the configuration, the registries of kinds and of planners and integrators, the rules' tables,
    the records and contracts, the state's layout, Algorithm 1); everything else lives in a layer's package."""
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= 10, top


VOCABULARY = ("apac_mj.types", "apac_mj.config", "apac_mj.kinds", "apac_mj.rules", "apac_mj.kinematics",
              "apac_mj.layout", "apac_mj.systems",
              "apac_mj.util.files", "apac_mj.util.overrides", "apac_mj.util.paths")


@pytest.mark.parametrize("code", ["import apac_mj", "import apac_mj.cli; apac_mj.cli.build_parser()",
                                  "import apac_mj.report", "import " + ", ".join(VOCABULARY)])
def test_the_face_and_the_command_line_load_without_torch(code: str):
    out = subprocess.run([sys.executable, "-c", f"{code}; import sys; print('torch' in sys.modules)"],
                         capture_output=True, text=True, check=True, cwd=PACKAGE.parent)
    assert out.stdout.strip() == "False", out


def test_every_public_name_resolves():
    import apac_mj

    for name in apac_mj.__all__:
        assert getattr(apac_mj, name) is not None, name
    assert apac_mj.train.__module__ == "apac_mj.run.trainer"
    assert apac_mj.AgentConfig is __import__("apac_mj.config", fromlist=["AgentConfig"]).AgentConfig
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        apac_mj.nope  # noqa: B018


def test_the_run_directory_imports_neither_the_plant_nor_the_learner():
    """run/run_dir.py reads and writes a run's files; a run is built from them in run/build.py."""
    reached = imports("apac_mj.run.run_dir", type_level=True)
    assert not {m for m in reached if m.startswith(("apac_mj.suite", "apac_mj.agent", "apac_mj.kinds",
                                                    "apac_mj.run.build", "apac_mj.run.rollout"))}, reached
    assert "apac_mj.run.run_dir" in imports("apac_mj.run.build")  # the builder reads the files through it
