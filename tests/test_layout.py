"""The package's folders are its layers: imports only go down, and no module imports itself
back through others (every import counted, those inside functions too)."""

from __future__ import annotations

import ast
import pathlib

import grounding_jax

PACKAGE = pathlib.Path(grounding_jax.__file__).resolve().parent
#: bottom to top; the package's own top-level modules (the public names, the CLIs) sit above
LAYERS = ("core", "sim", "envs", "learn", "robot", "sweep", "paper")
TOP = len(LAYERS)


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        rel = p.relative_to(PACKAGE).with_suffix("")
        if "assets" in rel.parts:  # one-off generators run as scripts, not package code
            continue
        parts = ("grounding_jax", *rel.parts)
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _imports(path: pathlib.Path, known: set[str]) -> set[str]:
    """The package's modules that ``path`` imports (a name imported from a package counts
    as the module of that name when there is one)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("grounding_jax")}
        elif isinstance(node, ast.ImportFrom) and node.module and \
                node.module.startswith("grounding_jax"):
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                found.add(sub if sub in known else node.module)
    return found


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else TOP


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(p, set(mods)) - {m} for m, p in mods.items()}


def test_every_module_is_in_a_layer():
    loose = [m for m in _modules() if _layer(m) == TOP and m.count(".") > 0
             and m.split(".")[1] not in ("show",)]
    assert not loose, f"modules outside the layer folders {LAYERS}: {loose}"


def test_imports_only_go_down():
    upward = [f"{m} ({LAYERS[_layer(m)] if _layer(m) < TOP else 'top'}) imports {d} "
              f"({LAYERS[_layer(d)] if _layer(d) < TOP else 'top'})"
              for m, deps in _graph().items() for d in sorted(deps) if _layer(d) > _layer(m)]
    assert not upward, "imports that go up a layer:\n" + "\n".join(upward)


def test_no_import_cycle():
    graph = _graph()
    state: dict[str, int] = {}  # 1 on the path, 2 done
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(" -> ".join(path[path.index(d):] + [m, d]) if d in path
                              else f"{m} -> {d}")
            elif d not in state:
                visit(d, path + [m])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_sweep_runner_imports_no_module_it_trains():
    for m, deps in _graph().items():
        if m.startswith("grounding_jax.sweep"):
            assert all(_layer(d) <= LAYERS.index("sweep") and not d.startswith(
                ("grounding_jax.learn", "grounding_jax.sim")) for d in deps), (m, deps)


def test_the_checker_sees_an_upward_import(tmp_path, monkeypatch):
    """The checks above can fail: a core module importing the paper's is caught."""
    fake = tmp_path / "grounding_jax"
    for p in _modules().values():
        dest = fake / p.relative_to(PACKAGE)
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_text(p.read_text())
    io_module = fake / "core" / "io.py"  # the AL experiments import it: a cycle too
    io_module.write_text("from grounding_jax.paper import al_experiments\n" + io_module.read_text())
    monkeypatch.setattr(__import__(__name__), "PACKAGE", fake)
    try:
        test_imports_only_go_down()
    except AssertionError as e:
        assert "grounding_jax.core.io (core) imports grounding_jax.paper.al_experiments" in str(e)
    else:
        raise AssertionError("an upward import went unseen")
    try:
        test_no_import_cycle()
    except AssertionError as e:
        assert "import cycles" in str(e)
    else:
        raise AssertionError("an import cycle went unseen")
