"""clpt's modules import one another without a circle: the graph of their
module-level imports (read with ast from clpt/**/*.py, not by importing) has
no cycle, and the library's functions import none of clpt's modules (such
an import only hides a circle; optional dependencies stay lazy, and the
command-line and benchmark front ends import per command)."""

from __future__ import annotations

import ast
from pathlib import Path

import clpt

ROOT = Path(clpt.__file__).resolve().parent
FRONT_ENDS = ("clpt.cli", "clpt.tools")  # packages that import per command


def _modules() -> dict[str, tuple[Path, bool]]:
    out = {}
    for p in sorted(ROOT.rglob("*.py")):
        parts = ("clpt",) + p.relative_to(ROOT).with_suffix("").parts
        is_pkg = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_pkg else parts)] = (p, is_pkg)
    return out


def _targets(node, module: str, is_pkg: bool, modules) -> set[str]:
    """The clpt modules an import statement imports (a package's own namespace
    when a name is not a submodule, as `from . import __version__`)."""
    out = set()
    if isinstance(node, ast.Import):
        return {a.name for a in node.names if a.name.split(".")[0] == "clpt" and a.name in modules}
    if node.level:
        base = module.split(".") if is_pkg else module.split(".")[:-1]
        base = base[:len(base) - (node.level - 1)]
        name = ".".join(base + ([node.module] if node.module else []))
    else:
        name = node.module or ""
    if name.split(".")[0] != "clpt":
        return out
    for a in node.names:
        sub = f"{name}.{a.name}"
        out.add(sub if sub in modules else name)
    return {m for m in out if m in modules}


def _module_level(tree):
    """Import statements that run when the module is imported (not in a function's body)."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            stack.extend(ast.iter_child_nodes(node))


def _function_level(tree):
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    yield node


def import_graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for m, (p, is_pkg) in modules.items():
        tree = ast.parse(p.read_text(), str(p))
        graph[m] = set().union(*[_targets(n, m, is_pkg, modules) for n in _module_level(tree)]) - {m}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the graph as [a, b, ..., a], or None."""
    state, path = {}, []

    def visit(v):
        state[v] = "open"
        path.append(v)
        for w in sorted(graph.get(v, ())):
            if state.get(w) == "open":
                return path[path.index(w):] + [w]
            if w not in state:
                found = visit(w)
                if found:
                    return found
        path.pop()
        state[v] = "done"
        return None

    for v in sorted(graph):
        if v not in state:
            found = visit(v)
            if found:
                return found
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_the_module_level_import_graph_has_no_cycle():
    graph = import_graph()
    assert "clpt.engine.device" in graph and "clpt.engine.passes" in graph["clpt.engine.device"]
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_library_functions_import_no_clpt_module():
    modules = _modules()
    found = []
    for m, (p, is_pkg) in modules.items():
        if any(m == f or m.startswith(f + ".") for f in FRONT_ENDS):
            continue
        tree = ast.parse(p.read_text(), str(p))
        for node in _function_level(tree):
            if _targets(node, m, is_pkg, modules):
                found.append(f"{p.relative_to(ROOT.parent)}:{node.lineno}: {ast.unparse(node)}")
    assert not found, "function-level imports of clpt modules:\n" + "\n".join(found)
