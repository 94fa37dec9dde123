"""The core's structure, read from its own imports (issue 23): wings import only downhill,
no project import inside a function but the justified lazy ones, every public name is
importable from its wing's face, and no private name crosses a wing."""

from __future__ import annotations

import ast
import importlib
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "cmm_core"

# Each wing and the wings it may import (README, "Layout"). Ground modules (units, _blas)
# may be imported by every wing.
ALLOWED = {
    "machine": set(),
    "gp": set(),
    "io": {"machine"},
    "gum": {"io"},
    "model": {"machine", "io"},
    "diagnosis": {"machine", "io", "model", "gp"},
    "export": {"machine", "io", "model"},
    "plan": {"machine", "io", "model", "diagnosis", "gum", "export"},
    "monitor": {"machine", "io", "model", "diagnosis", "gum", "export"},
    "analysis": {"machine", "io", "model", "diagnosis", "gp", "gum", "export", "monitor"},
    "cli": {"machine", "io", "model", "diagnosis", "gp", "gum", "export", "plan", "monitor",
            "analysis"},
}
GROUND = {"units", "_blas", ""}
WINGS = sorted(ALLOWED)


def _modules():
    for path in sorted(CORE.rglob("*.py")):
        parts = path.relative_to(CORE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield path, parts


def _imports(path, parts):
    """(target parts, imported names, node) for every project import in ``path``."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = list(parts if is_pkg else parts[:-1])
            base = base[:len(base) - (node.level - 1)]
            target = base + (node.module.split(".") if node.module else [])
            yield target, [a.name for a in node.names], node, tree


def _wing(parts):
    return parts[0] if parts and parts[0] in ALLOWED else ""


@pytest.mark.parametrize("wing", WINGS)
def test_a_wing_imports_only_the_wings_below_it(wing):
    wrong = []
    for path, parts in _modules():
        if _wing(parts) != wing:
            continue
        for target, _names, node, _tree in _imports(path, parts):
            tw = _wing(target)
            if tw and tw != wing and tw not in ALLOWED[wing]:
                wrong.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {'.'.join(target)}")
            if not tw and target and target[0] not in GROUND:
                wrong.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {target}")
    assert not wrong, wrong


def test_the_allowed_wings_form_no_circle():
    order = []
    left = dict(ALLOWED)
    while left:
        ready = [w for w, deps in left.items() if deps <= set(order)]
        assert ready, f"circle among {sorted(left)}"
        order += sorted(ready)
        for w in ready:
            del left[w]


def _import_module_calls(tree):
    """Every ``importlib.import_module(...)`` call (or ``import_module(...)``) in ``tree``:
    an import by name, which the wing checks above cannot read."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name == "import_module":
                yield node


def test_no_function_local_project_import_without_a_reason():
    """A project import inside a function is allowed only with a comment on its line or
    the line above saying why it is lazy (a heavy optional dependency); so is an import by
    name (``importlib.import_module``, the command line's commands, imported when they
    run). Module-level ``if TYPE_CHECKING:`` imports are not function-local (they still
    run downhill)."""
    unjustified = []
    for path, parts in _modules():
        lines = path.read_text().splitlines()
        tree = ast.parse(path.read_text())
        in_functions = {id(n) for f in ast.walk(tree)
                        if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
                        for n in ast.walk(f)}
        nodes = [node for _target, _names, node, _tree in _imports(path, parts)]
        for node in nodes + list(_import_module_calls(tree)):
            if id(node) not in in_functions:
                continue
            around = lines[node.lineno - 2] + lines[node.lineno - 1]
            if "lazy" not in around:
                unjustified.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not unjustified, unjustified


def test_no_private_name_crosses_a_wing():
    crossing = []
    for path, parts in _modules():
        for target, names, node, _tree in _imports(path, parts):
            if _wing(target) and _wing(target) != _wing(parts):
                crossing += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names
                             if n.startswith("_") and n != "__version__"]
    assert not crossing, crossing


def _public_names(path):
    """The public top-level names a module defines (functions, classes, assignments)."""
    for node in ast.parse(path.read_text()).body:
        names = []
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            names = [node.name]
        elif isinstance(node, ast.Assign):
            names = [n.id for t in node.targets for n in ast.walk(t) if isinstance(n, ast.Name)]
        yield from (n for n in names if not n.startswith("_"))


def _subpackages(wing):
    """The subpackages of a wing, as parts below it (``("proposals",)`` for plan)."""
    return sorted(p.parent.relative_to(CORE / wing).parts
                  for p in (CORE / wing).rglob("__init__.py") if p.parent != CORE / wing)


@pytest.mark.parametrize("wing", WINGS)
def test_every_public_name_is_importable_from_its_wing(wing):
    """Every public top-level name a wing's modules define is in the face's ``__all__``
    and is the very object of the module that defines it (names that two modules of a
    wing define are listed in ``SHADOWED``). A module of a subpackage (a module cut into
    one module per concept, ``plan/proposals/``) is held to the same, and its name is in
    the subpackage's face too; but for the subpackages ``BEHIND_THEIR_FACE``."""
    face = importlib.import_module(f"cmm_core.{wing}")
    missing = []
    for path in sorted((CORE / wing).rglob("*.py")):
        rel = path.relative_to(CORE / wing).with_suffix("").parts
        if rel[-1] == "__init__" or any(p.startswith("_") for p in rel) or any(
                (wing, *rel[:k]) in BEHIND_THEIR_FACE for k in range(1, len(rel))):
            continue
        module = importlib.import_module(".".join(("cmm_core", wing, *rel)))
        faces = [face] + [importlib.import_module(".".join(("cmm_core", wing, *rel[:k])))
                          for k in range(1, len(rel))]
        for name in _public_names(path):
            if (wing, name) in SHADOWED:
                continue
            if any(name not in f.__all__ or getattr(f, name) is not getattr(module, name)
                   for f in faces):
                missing.append(f"{'.'.join(rel)}.{name}")
    assert not missing, missing
    for name in face.__all__:
        assert hasattr(face, name), name
    for sub in _subpackages(wing):
        sub_face = importlib.import_module(".".join(("cmm_core", wing, *sub)))
        assert [n for n in sub_face.__all__ if not hasattr(sub_face, n)] == [], sub
        assert [n for n in sub_face.__all__ if n not in face.__all__
                or getattr(face, n) is not getattr(sub_face, n)] == [], sub


BEHIND_THEIR_FACE = {
    # one effect per module, reached through ``blocks.REGISTRY``: the blocks' face (and the
    # model's) carries what the fit, the simulator and the file readers name
    ("model", "blocks"),
}


SHADOWED = {
    # the same name in two modules of one wing: the face carries the first, the other is
    # imported from its module
    ("diagnosis", "ALPHA"),
    ("export", "read_points"),
    # each sub-command module of the CLI has its add_parser and run; the face carries
    # the first (export's), cli.commands imports the others by module
    ("cli", "add_parser"), ("cli", "run"),
}


def test_one_version_number_from_the_package_metadata():
    import tomllib

    import cmm_core

    with open(ROOT / "pyproject.toml", "rb") as f:
        assert cmm_core.__version__ == tomllib.load(f)["project"]["version"]


def test_no_module_imports_itself_round_a_circle():
    """Every project import, type-only ones included, runs one way: the modules form no
    circle (a circle means the concept was cut in two; farm-studio draws the same)."""
    graph: dict[str, set[str]] = {}
    names = {".".join(parts) for _path, parts in _modules()}
    for path, parts in _modules():
        me = ".".join(parts)
        edges = graph.setdefault(me, set())
        for target, imported, _node, _tree in _imports(path, parts):
            base = ".".join(target)
            for n in imported:  # ``from . import blocks`` names a module
                edges.add(f"{base}.{n}" if f"{base}.{n}" in names else base)
    within = {m: {t for t in ts if t in names and t != m} for m, ts in graph.items()}
    state: dict[str, int] = {}

    def visit(m, stack):
        state[m] = 1
        for t in within.get(m, ()):
            if state.get(t) == 1:
                raise AssertionError(" -> ".join(stack[stack.index(t):] + [t]))
            if t not in state:
                visit(t, stack + [t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])


# --- the app's wing (issue 36): app.py the frame, pages/ the page scripts, pages/ui the
# UI they share (Streamlit scans pages/*.py only, never the package below it)

PAGES_DIR = ROOT / "pages"
UI = PAGES_DIR / "ui"
FACES = {f"cmm_core.{w}" for w in WINGS} | {"cmm_core", "cmm_core.units"}
PAGE_SCRIPTS = sorted(PAGES_DIR.glob("*.py"))
UI_MODULES = sorted(UI.rglob("*.py"))
APP_FILES = [ROOT / "app.py", *PAGE_SCRIPTS, *UI_MODULES]


def _app_imports(path):
    """(imported module, its names, node, inside a function) for every import of an app
    file (the app imports absolutely)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    in_functions = {id(n) for f in ast.walk(tree)
                    if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
                    for n in ast.walk(f)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, [], node, id(node) in in_functions
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module, [a.name for a in node.names], node, id(node) in in_functions


def _project_targets(module, names):
    """The project modules an import names: ``from cmm_core import model`` names the face
    ``cmm_core.model``, ``from pages.ui import state`` the module ``pages.ui.state``."""
    if not module.startswith(("cmm_core", "pages")):
        return []
    subs = [f"{module}.{n}" for n in names
            if (ROOT / Path(*f"{module}.{n}".split("."))).with_suffix(".py").is_file()
            or (ROOT / Path(*f"{module}.{n}".split(".")) / "__init__.py").is_file()]
    return subs or [module]


@pytest.mark.parametrize("path", APP_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_app_imports_wing_faces_and_its_ui_only(path):
    """app.py and every page or UI module take the core through its wings' faces only, and
    the app's own code through ``pages.ui``: no page imports a page, no UI module a page,
    the frame no page script (it names them to ``st.Page`` as files)."""
    wrong = []
    for module, names, node, _lazy in _app_imports(path):
        for target in _project_targets(module, names):
            where = f"{path.relative_to(ROOT)}:{node.lineno} imports {target}"
            if target.startswith("cmm_core") and target not in FACES:
                wrong.append(where + " (not a wing's face)")
            elif target.startswith("pages") and not target.startswith("pages.ui"):
                wrong.append(where + " (a page script, or pages itself)")
    assert not wrong, wrong


def test_the_ui_package_imports_run_downhill():
    """Within ``pages.ui``: the panels use the shared modules, never the other way round,
    and the modules form no circle."""
    graph = {}
    for path in UI_MODULES:
        parts = path.relative_to(ROOT).with_suffix("").parts
        me = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        graph[me] = {t for m, names, _n, _l in _app_imports(path)
                     for t in _project_targets(m, names) if t.startswith("pages.ui") and t != me}
    up = [f"{m} imports {t}" for m, ts in graph.items() for t in ts
          if ".panels" in t and ".panels" not in m]
    assert not up, up
    done: list[str] = []
    left = dict(graph)
    while left:
        ready = [m for m, ts in left.items() if ts <= set(done) | {"pages.ui"}]
        assert ready, f"circle among {sorted(left)}"
        done += ready
        for m in ready:
            del left[m]


@pytest.mark.parametrize("path", APP_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_an_app_import_inside_a_function_states_its_reason(path):
    lines = path.read_text(encoding="utf-8").splitlines()
    unjustified = [f"{path.relative_to(ROOT)}:{node.lineno}"
                   for _m, _names, node, inside in _app_imports(path)
                   if inside and "lazy" not in lines[node.lineno - 2] + lines[node.lineno - 1]]
    assert not unjustified, unjustified


def test_the_core_never_imports_the_app_or_streamlit():
    wrong = []
    for path, _parts in _modules():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            # absolute imports only: ``from .app import`` is the CLI's own app command
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                    [node.module or ""] if isinstance(node, ast.ImportFrom)
                    and node.level == 0 else [])
            wrong += [f"{path.relative_to(ROOT)}:{node.lineno} {m}" for m in mods
                      if m.split(".")[0] in ("streamlit", "pages", "app", "serve",
                                             "cmm_error_lab_app")]
    assert not wrong, wrong


def test_pages_holds_page_scripts_and_the_ui_package_only():
    """Every ``pages/*.py`` is a page the frame navigates to (Streamlit would otherwise run
    a helper module as a page of its own); everything else under ``pages/`` is ``ui``."""
    frame = (ROOT / "app.py").read_text(encoding="utf-8")
    assert [p.name for p in PAGE_SCRIPTS if f'"pages/{p.name}"' not in frame] == []
    assert sorted(p.name for p in PAGES_DIR.iterdir()
                  if p.name != "__pycache__" and p.suffix != ".py") == ["ui"]


@pytest.mark.parametrize("path", [ROOT / "app.py", *PAGE_SCRIPTS], ids=lambda p: p.name)
def test_a_script_writes_no_bare_string_onto_its_page(path):
    """Streamlit's "magic" draws a bare expression of a script on the page: a string
    after the module docstring (an attribute's docstring, as a module would write one)
    appeared above the Interim check page's tabs."""
    body = ast.parse(path.read_text(encoding="utf-8")).body
    bare = [n.lineno for n in body[1:] if isinstance(n, ast.Expr)
            and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)]
    assert bare == [], f"{path.name}: bare strings at lines {bare}"


# --- names in prose: docstrings and comments went on naming modules after they moved into
# the wings (``cmm_core.gp_optimise`` for ``cmm_core.gp.optimise``, ``cmm_core.blocks``)

DOTTED = re.compile(r"cmm_core(?:\.\w+)+")
PROSE_FILES = sorted([*CORE.rglob("*.py"), *PAGES_DIR.rglob("*.py"),
                      *(ROOT / "bench").rglob("*.py"), ROOT / "app.py", ROOT / "serve.py"])


def _prose(path):
    """(line, text) of every comment and docstring of a file (string statements: module,
    class, function and attribute docstrings)."""
    src = path.read_text(encoding="utf-8")
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) \
                and isinstance(node.value.value, str):
            yield node.lineno, node.value.value


def _resolves(dotted: str) -> bool:
    """Whether ``cmm_core.a.b.c`` is a module, or attributes of the longest module prefix."""
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for name in parts[k:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


def test_every_dotted_name_in_prose_resolves():
    """Every ``cmm_core.xxx[.yyy]`` a docstring or comment of the core, the app or the
    benches names is an importable module or an attribute of one: a module that moves
    takes its references with it."""
    stale = [f"{path.relative_to(ROOT)}:{line} {ref}"
             for path in PROSE_FILES for line, text in _prose(path)
             for ref in sorted(set(DOTTED.findall(text))) if not _resolves(ref)]
    assert not stale, stale


def test_the_prose_check_finds_a_stale_name():
    text = "see :func:`~cmm_core.gp_optimise.run`."
    assert DOTTED.findall(text) == ["cmm_core.gp_optimise.run"]
    assert not _resolves("cmm_core.gp_optimise")
    assert not _resolves("cmm_core.io.no_such_name")
    assert _resolves("cmm_core.gp.optimise") and _resolves("cmm_core.io.DataError")
    assert _resolves("cmm_core.model.blocks.base.Block.correct")
