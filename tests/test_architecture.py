"""The house rules of docs/architecture.md, read from the source with ``ast``: every module sits in
one layer, imports only from its own layer or below, imports the project's modules at the top
(function-local imports only for the optional heavy dependencies and the sympy layer), and no
import circle exists, function-local imports included."""
import ast
import pathlib

import pytest

SRC = pathlib.Path(__file__).resolve().parents[1] / "src"

# bottom to top; a module may import its own layer and the layers before it
LAYERS = (
    # io.inputs (the one reader of users' files) sits with errors: model.params reads through it
    ("haa_sym.errors", "haa_sym._version", "haa_sym.io.inputs"),
    ("haa_sym.model",),
    ("haa_sym.io",),
    ("haa_sym.symbolic",),
    ("haa_sym.compiled",),
    ("haa_sym.loop",),
    ("haa_sym.analysis",),
    ("haa_sym.fit",),
    ("haa_sym.design",),
    ("haa_sym.robot",),
    ("haa_sym.explore",),
    ("haa_sym.check",),
    ("haa_sym.paper",),
    ("haa_sym.cli", "haa_sym.verify", "haa_sym"),
)
# what a function may import lazily: dependencies that are heavy to import and needed by few
# calls, the sympy layer (the numeric runtime never imports sympy) and the plotting module (it
# imports matplotlib: a command that draws nothing does not pay for it); pint (0.75 s to import
# and build its registry) only for a file written in units other than SI (haa_sym.model.units);
# panel and bokeh (the optional extra haa_sym[explore], 0.6 s to import; tornado is Bokeh's server) only
# by the explorer's page;
# scipy.signal (about 0.7 s, it pulls scipy.stats), scipy.stats and scipy.optimize (0.25-0.5 s) only
# by the few functions that use them (the cross-check's reference, a fit's figure, root finding),
# so that a command which does not need them starts without them (tests/test_cli_startup.py);
LAZY_ALLOWED = ("sympy", "dask", "distributed", "control", "matplotlib", "pint", "haa_sym.symbolic",
                "haa_sym.io.plots", "panel", "bokeh", "tornado", "scipy.signal", "scipy.stats", "scipy.optimize",
                "mujoco")


def _modules():
    for path in sorted((SRC / "haa_sym").rglob("*.py")):
        rel = path.relative_to(SRC).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _layer(module: str) -> int:
    best = None
    for i, prefixes in enumerate(LAYERS):
        for p in prefixes:
            if module == p or module.startswith(p + "."):
                if best is None or len(p) > best[1]:
                    best = (i, len(p))
    assert best is not None, f"{module} is in no layer of tests/test_architecture.py"
    return best[0]


def _imports(module: str, path: pathlib.Path):
    """(imported module, line, whether inside a function) for every import of ``path``."""
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []

    def visit(node, local):
        for child in ast.iter_child_nodes(node):
            inner = local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                out.extend((a.name, child.lineno, local) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    up = package.split(".")[: len(package.split(".")) - child.level + 1]
                    base = ".".join(up + ([base] if base else []))
                # "from pkg import mod" imports the submodule pkg.mod when it is one
                for a in child.names:
                    sub = f"{base}.{a.name}"
                    out.append((sub if _is_module(sub) else base, child.lineno, local))
            visit(child, inner)
    visit(tree, False)
    return out


def _is_module(name: str) -> bool:
    p = SRC / pathlib.Path(*name.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


MODULES = dict(_modules())


def test_every_module_has_a_layer():
    for module in MODULES:
        _layer(module)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_only_downward_and_at_the_top(module):
    bad = []
    for name, line, local in _imports(module, MODULES[module]):
        if name == "haa_sym" or name.startswith("haa_sym."):
            if _layer(name) > _layer(module):
                bad.append(f"line {line}: imports {name} from a higher layer")
            if local and not name.startswith(LAZY_ALLOWED):
                bad.append(f"line {line}: imports {name} inside a function")
    assert not bad, f"{module}: " + "; ".join(bad)


def test_no_import_circle():
    graph = {m: set() for m in MODULES}
    for module, path in MODULES.items():
        for name, _line, _local in _imports(module, path):
            target = name
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            # a package's __init__ re-exporting its own modules is not a circle of the code
            if target and target != module and not module.startswith(target + "."):
                graph[module].add(target)
    index, low, stack, on, circles = {}, {}, [], set(), []

    def strongconnect(v):            # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strongconnect(w)
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
                circles.append(sorted(comp))
    for v in graph:
        if v not in index:
            strongconnect(v)
    assert not circles, f"import circles: {circles}"


# --- the imports that are not import statements -----------------------------------------------------
# haa_sym's public names and haa-sym's commands are imported on first use through importlib
# (haa_sym.__getattr__, haa_sym.cli.COMMANDS; docs/startup.md), which the ast rules above do not
# see: the modules they name obey the same layers.
def _dynamic_imports():
    import haa_sym
    import haa_sym.cli
    yield from (("haa_sym", m) for m in sorted(set(haa_sym._LAZY.values())))
    yield from (("haa_sym.cli", m) for m in sorted({m for m, _help in haa_sym.cli.COMMANDS.values()}))


@pytest.mark.parametrize("importer,module", list(_dynamic_imports()))
def test_lazy_imports_name_modules_downward(importer, module):
    assert module in MODULES, f"{importer} names {module}, which is no module of src/haa_sym"
    assert _layer(module) <= _layer(importer), f"{importer} imports {module} from a higher layer"


def test_every_public_name_resolves():
    """Every name of ``haa_sym.__all__`` is an attribute of the package (``from haa_sym import X``
    and ``haa_sym.X``), the object of the module that defines it, and listed by ``dir``."""
    import importlib

    import haa_sym
    assert set(haa_sym.__all__) <= set(dir(haa_sym))
    for name in haa_sym.__all__:
        value = getattr(haa_sym, name)
        assert value is getattr(importlib.import_module(haa_sym._LAZY[name]), name), name
    namespace: dict = {}
    exec("from haa_sym import *", namespace)
    assert set(haa_sym.__all__) <= set(namespace)
    assert haa_sym.__version__ == haa_sym._version.version()
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        haa_sym.not_a_name


def test_every_command_has_its_arguments_and_handler():
    """Each command of haa_sym.cli.COMMANDS is defined by its module's ARGUMENTS, and every
    command a module defines is listed (no command left out of ``haa-sym --help``)."""
    import importlib

    import haa_sym.cli
    listed: dict = {}
    for command, (module, _help) in haa_sym.cli.COMMANDS.items():
        listed.setdefault(module, set()).add(command)
    for module, commands in listed.items():
        arguments = importlib.import_module(module).ARGUMENTS
        assert set(arguments) == commands, module
        assert all(callable(add) and callable(run) for add, run in arguments.values()), module
