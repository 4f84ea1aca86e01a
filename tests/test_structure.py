"""Structure of the ``hapid`` package, read from its source (AST only: nothing is imported).

- **No import cycle.** Nodes are hapid's modules (``hapid/x/__init__.py`` is the package
  ``hapid.x``). Every ``import`` / ``from … import`` counts, at any depth (module level,
  function bodies, class bodies), with relative imports resolved; only imports under
  ``if TYPE_CHECKING:`` are left out (they never run). ``from p import y`` is an edge to the
  submodule ``p.y`` when ``p/y.py`` or ``p/y/`` exists, else to ``p`` itself; ``import a.b.c``
  is an edge to ``a.b.c``. The import of parent packages that Python performs before a
  submodule is not an edge. A package ``__init__`` importing its own submodules is an ordinary
  edge (``__init__`` → submodule); a cycle appears only if a submodule then imports something
  that leads back into that ``__init__`` (e.g. ``from ..pkg import name`` inside ``pkg``),
  which is exactly the partially-initialized-module case.
- **No module longer than** :data:`MAX_LINES` **lines.**
- **Every function-local import says why** with a trailing ``# local: <reason>`` comment on
  one of its lines (the reasons in use: an optional dependency, CLI start-up time measured with
  ``python -X importtime``, or a cycle). The comment is the allow-list.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "hapid"
MAX_LINES = 500
LOCAL_REASON = re.compile(r"#\s*local:\s*\S")


def module_name(path: Path, root: Path) -> str:
    parts = ["hapid", *path.relative_to(root).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for p in sorted(root.rglob("*.py"))}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST, in_function: bool = False):
    """``(node, in_function)`` for every import in ``tree``, skipping ``if TYPE_CHECKING:``."""
    for child in ast.iter_child_nodes(tree):
        if isinstance(child, ast.If) and _is_type_checking(child.test):
            for sub in child.orelse:
                yield from _imports(ast.Module(body=[sub], type_ignores=[]), in_function)
            continue
        if isinstance(child, ast.Import | ast.ImportFrom):
            yield child, in_function
        fn = isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
        yield from _imports(child, in_function or fn)


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module → the hapid modules it imports (the rules in the module docstring)."""
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        targets: set[str] = set()
        for node, _ in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                wanted = [a.name for a in node.names]
            else:
                if node.level:
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    src = ".".join(base + ([node.module] if node.module else []))
                else:
                    src = node.module or ""
                wanted = [
                    f"{src}.{a.name}" if f"{src}.{a.name}" in mods else src for a in node.names
                ]
            for t in wanted:
                while t and t not in mods:  # an attribute path: its longest module prefix
                    t = t.rpartition(".")[0]
                if t and t != name:
                    targets.add(t)
        graph[name] = targets
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as ``[a, b, …, a]``, or ``None`` (iterative depth-first search)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    for start in sorted(graph):
        if start in state:
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        state[start] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                state[node] = 2
                stack.pop()
                path.pop()
            elif state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            elif nxt not in state:
                state[nxt] = 1
                stack.append((nxt, iter(sorted(graph.get(nxt, ())))))
                path.append(nxt)
    return None


def unexplained_local_imports(path: Path) -> list[str]:
    """``'file:line: statement'`` for each function-local import without ``# local:``."""
    text = path.read_text()
    lines = text.splitlines()
    bad = []
    for node, local in _imports(ast.parse(text, str(path))):
        span = lines[node.lineno - 1 : node.end_lineno]
        if local and not any(LOCAL_REASON.search(line) for line in span):
            bad.append(f"{path}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    return bad


def long_modules(root: Path = ROOT) -> list[str]:
    return [
        f"{p.relative_to(root.parent)}: {n} lines"
        for p in sorted(root.rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    ]


def test_graph_covers_the_package():
    mods = modules()
    graph = import_graph(mods)
    assert {"hapid", "hapid.io", "hapid.cli", "hapid.control._kernels"} <= set(graph)
    # a relative import of a sibling submodule, one two levels up, and a name of a package
    assert "hapid.control._lapack" in graph["hapid.control._kernels"]
    assert "hapid.io" in graph["hapid.tune._files"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph(modules()))
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_modules_are_short():
    assert long_modules() == [], f"modules over {MAX_LINES} lines (split them)"


def test_local_imports_say_why():
    bad = [line for path in sorted(ROOT.rglob("*.py")) for line in unexplained_local_imports(path)]
    assert bad == [], "function-local imports need '# local: <reason>':\n" + "\n".join(bad)


@pytest.fixture
def fake_pkg(tmp_path):
    root = tmp_path / "hapid"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    return root


def test_checks_catch_violations(fake_pkg):
    """Each check fails on a planted violation (and passes on the clean variant)."""
    root = fake_pkg
    (root / "sub" / "__init__.py").write_text("from ._b import f\n")
    (root / "sub" / "_b.py").write_text("def f():\n    from .. import a\n")
    (root / "a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import hapid.sub\n"
    )
    mods = modules(root)
    assert find_cycle(import_graph(mods)) is None  # TYPE_CHECKING does not count
    # a local import back up the tree closes a cycle through the package __init__
    (root / "a.py").write_text("from .sub import f\n")
    assert find_cycle(import_graph(modules(root))) == [
        "hapid.a",
        "hapid.sub",
        "hapid.sub._b",
        "hapid.a",
    ]
    # `from . import _b` inside the package is an edge to the submodule, not to __init__
    (root / "sub" / "_c.py").write_text("from . import _b\n")
    assert import_graph(modules(root))["hapid.sub._c"] == {"hapid.sub._b"}

    assert unexplained_local_imports(root / "sub" / "_b.py") != []
    (root / "sub" / "_b.py").write_text("def f():\n    from .. import a  # local: cycle: a <-> b\n")
    assert unexplained_local_imports(root / "sub" / "_b.py") == []
    (root / "sub" / "_b.py").write_text(
        "def f():\n    from .. import (\n        a,\n    )  # local: optional dependency\n"
    )
    assert unexplained_local_imports(root / "sub" / "_b.py") == []

    assert long_modules(root) == []
    (root / "big.py").write_text("x = 1\n" * (MAX_LINES + 1))
    assert long_modules(root) == [f"hapid/big.py: {MAX_LINES + 1} lines"]
