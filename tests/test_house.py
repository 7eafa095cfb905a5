"""The house (issue 52, item 8; docs/where-things-are.md): no import circle among the packages' modules,
no module over 480 lines, and ``mer_data`` never imports ``mer_models``. Read from the source (AST),
no import runs; a failure lists the offenders only."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAX_LINES = 480
# Long modules allowed over the limit: none (each was split by its job when the issue-49..54 branches merged).
OVER_LENGTH_ALLOWED: set[str] = set()


def _modules() -> dict[str, Path]:
    out = {}
    for f in sorted([*REPO.glob("mer_data/**/*.py"), *REPO.glob("mer_models/**/*.py")]):
        parts = f.relative_to(REPO).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package modules ``name`` imports, at any depth (a function's lazy import is a dependency too),
    except in a module-level ``__getattr__`` (PEP 562): a lazy re-export that runs only when the name is
    asked for, after the module is loaded (``mer_models.config`` re-exports :mod:`mer_models.run_config`)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = {id(n) for f in tree.body if isinstance(f, ast.FunctionDef) and f.name == "__getattr__" for n in ast.walk(f)}
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    deps = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                deps.add(full if full in modules else base)
        elif isinstance(node, ast.Import):
            deps.update(a.name for a in node.names)
    return {d for d in deps if d in modules and d != name}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_circle_finder_finds_a_lazy_circle(tmp_path):
    """The finder sees a circle closed by an import inside a function (as train.py <-> warm.py was)."""
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("def f():\n    from pkg.b import g\n")
    b.write_text("from pkg.a import f\n")
    mods = {"pkg.a": a, "pkg.b": b}
    assert _circles({m: _imports(m, p, mods) for m, p in mods.items()}) == [["pkg.a", "pkg.b"]]
    a.write_text("def __getattr__(name):\n    from pkg.b import g\n    return g\n")  # a PEP 562 re-export
    assert _circles({m: _imports(m, p, mods) for m, p in mods.items()}) == []


def test_no_import_circle_and_mer_data_never_imports_mer_models():
    modules = _modules()
    graph = {m: _imports(m, p, modules) for m, p in modules.items()}
    assert not _circles(graph), f"import circles: {_circles(graph)}"
    upward = sorted(f"{m} -> {d}" for m, deps in graph.items() if m.startswith("mer_data") for d in deps if d.startswith("mer_models"))
    assert not upward, upward


def test_no_module_over_480_lines():
    lengths = {str(p.relative_to(REPO)): len(p.read_text(encoding="utf-8").splitlines()) for p in _modules().values()}
    long = {f: n for f, n in lengths.items() if n > MAX_LINES and f not in OVER_LENGTH_ALLOWED}
    assert not long, f"modules over {MAX_LINES} lines (split them by job): {long}"
    stale = sorted(f for f in OVER_LENGTH_ALLOWED if lengths.get(f, 0) <= MAX_LINES)
    assert not stale, f"no longer over {MAX_LINES} lines: take them off OVER_LENGTH_ALLOWED: {stale}"
