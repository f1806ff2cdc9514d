"""``dfc`` has no import circles: the import graph of its modules, read from the source with ``ast``, has no cycle
between modules, nor between its packages: each package is one node made of its own modules (``dfc.geometry``:
``curves``, ``mesh``, ...; ``dfc.geometry.sources``: its readers), each top-level module one node (``dfc.codec``).

Every import counts: at module level and inside functions (a function-level import is a dependency all the same;
deferring it only hides the circle from the interpreter). ``TYPE_CHECKING`` blocks are skipped. A module
imports a package when it imports a name from the package's ``__init__``; ``from pkg import sub`` imports the
submodule ``pkg.sub`` when there is one. Importing ``dfc`` itself (the package's ``__init__``: version, errors and
lazy names) does not count as importing its subpackages."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dfc"


_PACKAGES = {".".join(p.parent.relative_to(ROOT).parts) for p in PACKAGE.rglob("__init__.py")}


def _modules() -> dict[str, Path]:
    """Module name → file, for every module of ``dfc`` (packages by their ``__init__``)."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The ``dfc`` modules that module ``name`` (at ``path``) imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()

    def resolve(module: str) -> str | None:
        while module and module not in modules:
            module = module.rpartition(".")[0]
        return module or None

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                found.update(resolve(a.name) for a in child.names if a.name.split(".")[0] == "dfc")
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")
                    base = base[:len(base) - child.level + 1]
                    module = ".".join(base + ([child.module] if child.module else []))
                else:
                    module = child.module or ""
                if module.split(".")[0] != "dfc":
                    continue
                for alias in child.names:
                    sub = f"{module}.{alias.name}"
                    found.add(sub if sub in modules else resolve(module))
            visit(child)

    visit(ast.parse(path.read_text(), filename=str(path)))
    found.discard(None)
    found.discard(name)
    return found


def _graph() -> dict[str, set[str]]:
    """Module → the modules it imports (``dfc`` itself left out)."""
    modules = _modules()
    return {name: _imports(name, path, modules) - {"dfc"} for name, path in modules.items()}


def _unit(module: str, modules=None) -> str:
    """The package whose own module ``module`` is (``dfc.geometry.sources`` for ``dfc.geometry.sources.svg``, itself
    for a package), or ``module`` itself when it is a top-level module (``dfc.codec``)."""
    package = module if module in _PACKAGES else module.rpartition(".")[0]
    return module if package == "dfc" else package


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def connect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return sorted(out)


def _edges(graph):
    return [(a, b) for a, targets in graph.items() for b in targets]


def test_the_graph_sees_known_edges():
    graph = _graph()
    assert "dfc.rate" in graph["dfc.codec"]
    assert "dfc.settings" in graph["dfc.cli.encode"]
    assert "dfc.field.model" in graph["dfc.train.fit"]  # from ..field.model import FieldModel
    assert "dfc.train.distributed" in graph["dfc.codec"]  # from .train import distributed, inside a function


def test_no_import_circle_between_modules():
    assert _cycles(_graph()) == []


def test_no_import_circle_between_subpackages():
    graph = _graph()
    units = {}
    for a, b in _edges(graph):
        if _unit(a) != _unit(b):
            units.setdefault(_unit(a), set()).add(_unit(b))
    assert _cycles(units) == []


def test_bench_does_not_import_the_command_line():
    graph = _graph()
    assert [(a, b) for a, b in _edges(graph) if _unit(a) == "dfc.bench" and _unit(b) == "dfc.cli"] == []
