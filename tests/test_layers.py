"""The package's layers, read from every module's imports (``ast``): imports only go down, and no module imports
itself round a cycle.  ARCHITECTURE.md names the layers; a module joins the first whose prefix it starts with.

An import inside ``if __name__ == "__main__":`` is a command's entry point (``python -m disent.models.shipped``
hands over to :mod:`disent.ship`), not a dependency of the module, and is not read."""

import ast
from pathlib import Path

import disent

PACKAGE = Path(disent.__file__).parent
LAYERS = (  # lowest first: (name, module prefixes)
    (
        "core",
        (
            "disent.render",
            "disent.losses",
            "disent.regions",
            "disent.models",
            "disent.data",
            "disent.storage",
            "disent.config",
            "disent.optim",
            "disent.images",
            "disent.runtime",
        ),
    ),
    # what training's validation, its fitted E_recon-L targets and its eval.json read: the core's measuring tools
    (
        "measures",
        (
            *("disent.eval.metrics", "disent.eval.scoring", "disent.eval.trivial"),
            *("disent.lighting.posterior", "disent.lighting.order", "disent.lighting.texture"),
        ),
    ),
    ("targets", ("disent.lighting.targets", "disent.eval.evaluate")),
    ("train", ("disent.train", "disent.stack", "disent.together")),
    ("the run catalogue", ("disent.runs",)),  # finding, reading and labelling runs: what the studies measure
    ("studies", ("disent.eval", "disent.edit", "disent.lighting", "disent.bench", "disent.photos", "disent.ship")),
    ("publishing and the report", ("disent.publish", "disent.report", "disent.__main__", "disent")),
)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in PACKAGE.rglob("*.py")}


def layer_of(module: str) -> int:
    return next(
        i for i, (_, prefixes) in enumerate(LAYERS) for p in prefixes if module == p or module.startswith(p + ".")
    )


def imported(node: ast.ImportFrom | ast.Import) -> list[str]:
    """The package's modules an import statement loads (``from a.b import c``: ``a.b.c`` where that is a module)."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    elif node.level == 0 and node.module:
        names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in MODULES else node.module for a in node.names]
    else:
        names = []
    out = []
    for name in names:
        while name and name not in MODULES:
            name = name.rpartition(".")[0]
        if name.startswith("disent"):
            out.append(name)
    return out


def imports_of(module: str) -> dict[str, int]:
    """``{imported module: line}`` of ``module``, entry points under a ``__main__`` guard left out."""
    tree = ast.parse(MODULES[module].read_text())
    guarded = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "__name__" in ast.unparse(node.test) and "__main__" in ast.unparse(node.test):
            guarded |= {id(n) for n in ast.walk(node)}
    found = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in guarded:
            for name in imported(node):
                if name != module:
                    found.setdefault(name, node.lineno)
    return found


GRAPH = {m: imports_of(m) for m in MODULES}


def test_every_module_has_a_layer():
    assert all(layer_of(m) is not None for m in MODULES)


def test_imports_only_go_down():
    up = [
        f"{m} ({LAYERS[layer_of(m)][0]}) imports {t} ({LAYERS[layer_of(t)][0]}), line {line}"
        for m, targets in GRAPH.items()
        for t, line in targets.items()
        if layer_of(t) > layer_of(m) and not m.startswith(t + ".")  # a package's __init__ is loaded with it: fine
    ]
    assert not up, "\n".join(up)


def cycles(graph: dict) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    assert cycles(GRAPH) == []


def test_the_cycle_finder_finds_a_cycle_and_the_layer_check_an_upward_import():
    """The checks themselves: a made-up graph with a cycle is found, and a core module importing the report is up."""
    assert cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]
    assert layer_of("disent.render") < layer_of("disent.train") < layer_of("disent.report.front")
