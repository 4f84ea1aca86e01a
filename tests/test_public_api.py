"""One result convention, enforced on the whole public API: no public function returns a bare
``dict`` or ``tuple`` of results (a typed result, or a ``NamedTuple`` of arrays, instead).

The scan reads every public function of every public hapid module (the names a package's
``__init__`` re-exports, the top-level functions of a public module) and flags one whose
return annotation is ``dict``/``tuple``/``list[dict]`` or whose body returns a dict or tuple
display. What is data rather than a result is listed in ``DATA`` with the reason; a new entry
there is a design decision, not a way to pass the test.
"""

import ast
import importlib
import inspect
import pkgutil
import textwrap

import hapid

#: public functions whose dict/tuple return is data, not a result (name → why)
DATA = {
    # matplotlib's own convention: a figure and its axes
    **{
        f"hapid.plot.{n}": "(fig, axes), matplotlib's convention"
        for n in (
            "coherence",
            "frf_overview",
            "impedance_fit",
            "impedance_h1",
            "loci",
            "pphat",
            "predictive_band",
            "robust_histograms",
            "sigma_T_minus_I",
            "singular_values",
            "sweep",
        )
    },  # fmt: skip
    # configuration read from or written to TOML/JSON: a mapping by nature
    "hapid.scene.load_scene": "a scene file's TOML content",
    "hapid.scene.merge": "a scene's configuration (TOML sections)",
    "hapid.scene.set_option": "a scene's configuration (TOML sections)",
    "hapid.design.commands": "argv per stage, the commands the design route runs",
    "hapid.impedance_frf.model_units": "unit labels of M, B, K",
    "hapid.io.load_model_metadata": "the free-form entries stored beside a model",
    "hapid.uncertainty.measured_data": "a samples file's 'measured' entry (file content)",
    # pytrees of constraint values keyed by constraint name, inside the jitted objective
    "hapid.tune.scenario_constraints": "jittable pytree: constraint name → values",
    "hapid.tune.aggregate": "jittable pytree: constraint name → CVaR value",
    "hapid.io.jsonable": "converts any value to JSON-ready values (a dict stays a dict)",
    "hapid.fit.physics_warnings": "the warning messages, one string each",
    "hapid.uncertainty.pose_grid": "a list of (x, y, z) offsets (m), the poses to study",
}


def _public_functions():
    """``{qualified name: function}`` of hapid's public API."""
    out = {}
    mods = ["hapid"] + [
        m.name for m in pkgutil.walk_packages(hapid.__path__, "hapid.")
        if not any(p.startswith("_") for p in m.name.split(".")[1:])
    ]  # fmt: skip
    for name in mods:
        mod = importlib.import_module(name)
        is_pkg = hasattr(mod, "__path__")
        names = list(vars(mod)) + list(getattr(mod, "__all__", []))  # lazy (PEP 562) names too
        for attr in dict.fromkeys(names):
            obj = getattr(mod, attr)
            if attr.startswith("_") or not inspect.isfunction(obj):
                continue
            if not obj.__module__.startswith("hapid"):
                continue
            if not is_pkg and obj.__module__ != name:
                continue  # imported into a plain module: not its API
            out[f"{name}.{attr}"] = obj
    return out


def _own_returns(fn_node):
    """Return statements of the function itself (not of nested functions or lambdas)."""
    stack = list(fn_node.body)
    while stack:
        node = stack.pop()
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda | ast.ClassDef):
            continue
        if isinstance(node, ast.Return) and node.value is not None:
            yield node.value
        stack.extend(ast.iter_child_nodes(node))


def _returns_bare(fn) -> str | None:
    """Why ``fn`` returns a bare dict/tuple, or ``None``."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    node = next(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef))
    ann = ast.unparse(node.returns) if node.returns is not None else ""
    if ann.split("[")[0] in ("dict", "tuple", "Dict", "Tuple") or ann.startswith(
        ("list[dict", "list[tuple")
    ):
        return f"annotated -> {ann}"
    for v in _own_returns(node):
        if isinstance(v, ast.Dict | ast.DictComp | ast.Tuple):
            return f"returns {ast.unparse(v)[:60]}"
    return None


def test_no_public_function_returns_a_bare_dict_or_tuple():
    funcs = _public_functions()
    assert len(funcs) > 150  # the scan sees the API (a broken walk would pass vacuously)
    bad = {n: why for n, f in funcs.items() if n not in DATA and (why := _returns_bare(f))}
    assert not bad, "\n".join(f"{n}: {w}" for n, w in sorted(bad.items()))
    stale = sorted(n for n in DATA if n not in funcs or _returns_bare(funcs[n]) is None)
    assert not stale, f"DATA entries that no longer apply: {stale}"
