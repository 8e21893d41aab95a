"""The one registry (apac_mj.util.registry.Registry) and the four that are instances of it."""
import pytest

from apac_mj.util.registry import Registry


def make() -> Registry[int]:
    r: Registry[int] = Registry("thing")
    r.register("b", 2)
    r.register("a", 1)
    return r


def test_names_keep_the_registration_order():
    r = make()
    assert r.names() == ("b", "a") and list(r) == ["b", "a"] and len(r) == 2
    assert r.items() == [("b", 2), ("a", 1)] and r.values() == [2, 1]
    assert "a" in r and "c" not in r
    assert r.get("a") == 1


def test_a_taken_name_is_refused_unless_replaced():
    r = make()
    with pytest.raises(ValueError, match=r"thing 'b' is already registered \(pass replace=True to redefine it\)"):
        r.register("b", 20)
    assert r.get("b") == 2
    with pytest.raises(ValueError, match="already registered"):
        r.check_new("b")
    r.check_new("c")  # a free name passes
    assert r.register("b", 20, replace=True) == 20
    assert r.names() == ("b", "a") and r.get("b") == 20  # replaced in its place
    assert r.replace("a", 10) == 10 and r.replace("c", 3) == 3  # replace also adds, after the others
    assert r.items() == [("b", 20), ("a", 10), ("c", 3)]


def test_unregister_removes_and_refuses_an_unknown_name():
    r = make()
    assert r.unregister("b") == 2
    assert r.names() == ("a",) and "b" not in r
    with pytest.raises(KeyError, match=r"no thing 'b' is registered; registered: a"):
        r.unregister("b")
    r.unregister("a")
    with pytest.raises(KeyError, match="registered: none"):
        r.get("a")


def test_an_unknown_name_lists_the_known_ones():
    r = make()
    with pytest.raises(KeyError, match=r"no thing 'zz' is registered; registered: b, a"):
        r.get("zz")
    with pytest.raises(KeyError, match="registered: b, a"):
        r.get(["unhashable"])  # type: ignore[arg-type]


def test_messages_and_error_type_are_the_registry_s_own():
    class Unknown(ValueError, KeyError):
        pass

    r: Registry[type] = Registry("table", error=Unknown, unknown="unknown {what} {name!r}; known: {names}",
                                 duplicate="{what} {name!r} is taken ({item.__qualname__})")
    r.register("x", int)
    with pytest.raises(Unknown, match=r"unknown table 'y'; known: x"):
        r.get("y")
    with pytest.raises(ValueError, match=r"table 'x' is taken \(int\)"):
        r.register("x", float)
    with pytest.raises(TypeError, match="must be a KeyError"):
        Registry("thing", error=ValueError)  # type: ignore[arg-type]


def test_the_four_registries_are_registries():
    from apac_mj import kinds, rules
    from apac_mj.report import figures
    from apac_mj.suite import task_spec

    assert isinstance(kinds._KINDS, Registry) and kinds._KINDS.names() == kinds.names()
    assert isinstance(rules._TABLES, Registry) and dict(rules._TABLES.items()) == rules.tables()
    assert isinstance(figures._FIGURES, Registry) and figures._FIGURES.values() == figures.registered_figures()
    assert isinstance(task_spec._REGISTERED, Registry)


def test_the_four_registries_keep_their_messages():
    from apac_mj import kinds, rules
    from apac_mj.report import figures
    from apac_mj.suite import task_spec

    with pytest.raises(kinds.UnknownKindError, match="unknown agent kind 'nope'; registered kinds: ddpg, spac, apac"):
        kinds.get("nope")
    with pytest.raises(ValueError, match="agent kind 'apac' is already registered"):
        kinds.register(kinds.get("apac"))
    with pytest.raises(ValueError, match=r"parameter table 'kalman' is already registered \(KalmanParams\)"):
        rules.register(_other_kalman())
    assert rules.register(rules.KalmanParams) is rules.KalmanParams  # again: a no-op
    first = figures.registered_figures()[0]
    with pytest.raises(ValueError, match=f"a figure '{first.file}' is already registered"):
        figures.register_figure(first)
    with pytest.raises(KeyError, match="no figure 'fig99.png' is registered; registered: fig3"):
        figures.unregister_figure("fig99.png")
    with pytest.raises(KeyError, match="task 'nope' was not registered at run time"):
        task_spec.unregister_task("nope")
    with pytest.raises(task_spec.TaskSpecError, match="task 'changing_target' already exists"):
        task_spec.register_task(task_spec.load_task("changing_target"))


def test_a_registered_task_is_known_by_name_until_unregistered():
    from apac_mj.suite import task_spec

    spec = task_spec.load_task("changing_target").replace(name="registry_probe", zone_radius=1.0)
    assert task_spec.register_task(spec) is spec
    try:
        assert "registry_probe" in task_spec.task_names() and task_spec.load_task("registry_probe") is spec
        again = spec.replace(zone_radius=2.0)
        task_spec.register_task(again, replace=True)
        assert task_spec.load_task("registry_probe") is again
    finally:
        task_spec.unregister_task("registry_probe")
    assert "registry_probe" not in task_spec.task_names()


def _other_kalman() -> type:
    """Another dataclass under the taken table name "kalman"."""
    import dataclasses
    from typing import ClassVar

    @dataclasses.dataclass(frozen=True)
    class Other:
        table: ClassVar[str] = "kalman"

    return Other
