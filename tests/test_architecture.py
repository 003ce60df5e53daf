"""The house rules (docs/architecture.md), checked on the source instead of remembered:

* the compute core never imports the web framework, the database, the viewer, the hardware or
  any service package; ``app/domain`` (the core's roots) imports only the standard library;
* ``hardware`` never imports ``app``;
* the job engine (``app/runtime``) reaches the kinds only through its registry;
* no loose module in ``app/`` but the entry points;
* job kinds never import each other (what several kinds share lives in ``app/jobs``: inputs,
  params, jetting_inputs; math in the core);
* job kinds and their shared helpers (``app/jobs``) never query the database: they read
  through their context (``ctx.reads()``, :class:`app.runtime.reads.JobReads`), never a session
  nor the runtime behind it;
* no import cycles between modules (function-local imports included);
* every module can be read in one sitting.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE = ("geometry", "probing", "reconstruction", "registration", "compensation", "jetting", "five_axis", "slicing",
        "gcode", "reference", "calibration", "circuits")
FORBIDDEN_IN_CORE = ("fastapi", "starlette", "sqlmodel", "sqlalchemy", "viser", "hardware", "huey", "uvicorn",
                     "app.api", "app.jobs", "app.viewer", "app.platform", "app.parts", "app.machines",
                     "app.runtime", "app.reporting", "app.main")
FORBIDDEN_IN_JOBS = ("sqlmodel", "sqlalchemy", "app.platform.db", "app.platform.lookup")
ENTRY_POINTS = {"app.main", "app.cli", "app.demo"}  # the only modules at app/'s top
MAX_MODULE_LINES = 500
# import cycles that exist today; the list may only shrink
KNOWN_CYCLES: set[frozenset[str]] = set()


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for top in ("app", "hardware") for p in (ROOT / top).rglob("*.py")}


def _runtime_nodes(tree: ast.AST):  # type: ignore[no-untyped-def]
    """Every node except those under ``if TYPE_CHECKING:`` (type-only imports run never)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and isinstance(child.test, ast.Name) and child.test.id == "TYPE_CHECKING":
                stack.extend(child.orelse)
                continue
            stack.append(child)


def _imports(path: Path, module: str) -> set[str]:
    """Every module ``path`` imports when it runs, anywhere in it (top level or inside functions)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in _runtime_nodes(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


MODULES = _modules()
IMPORTS = {name: _imports(path, name) for name, path in MODULES.items()}


def _internal(name: str) -> str | None:
    """The module of ours that an imported name refers to (longest match), if any."""
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


@pytest.mark.parametrize("package", CORE)
def test_the_compute_core_is_pure(package):
    offenders = {(module, imported) for module, imported_names in IMPORTS.items()
                 if module.startswith(f"app.{package}") for imported in imported_names
                 if any(imported == f or imported.startswith(f"{f}.") for f in FORBIDDEN_IN_CORE)}
    assert offenders == set()


def test_the_cores_roots_import_only_the_standard_library():
    offenders = {(m, i) for m, names in IMPORTS.items() if m.startswith("app.domain") for i in names
                 if i.split(".")[0] not in sys.stdlib_module_names and not i.startswith("app.domain")}
    assert offenders == set()


def test_the_job_engine_reaches_kinds_only_through_the_registry():
    offenders = {(m, i) for m, names in IMPORTS.items() if m.startswith("app.runtime.") and m != "app.runtime.registry"
                 for i in names if i.startswith("app.jobs.kinds")}
    assert offenders == set()


def test_no_loose_module_in_app_but_the_entry_points():
    loose = {name for name, path in MODULES.items() if name.startswith("app.") and name.count(".") == 1
             and path.name != "__init__.py" and name not in ENTRY_POINTS}
    assert loose == set(), "put it in the package that says what it is (docs/architecture.md)"


def test_hardware_never_imports_app():
    offenders = {(m, i) for m, names in IMPORTS.items() if m.startswith("hardware") for i in names
                 if i == "app" or i.startswith("app.")}
    assert offenders == set()


def _kind_imports(imports: dict[str, set[str]]) -> set[tuple[str, str]]:
    """(kind, kind it imports) pairs among ``imports`` (module -> names it imports)."""
    prefix = "app.jobs.kinds."
    return {(m[len(prefix):], _internal(i)[len(prefix):]) for m, names in imports.items() if m.startswith(prefix)
            for i in names if (_internal(i) or "").startswith(prefix) and _internal(i) != m}


def test_job_kinds_never_import_each_other():
    assert _kind_imports(IMPORTS) == set(), "a kind -> kind import: move the shared code out of the kinds " \
        "(app/jobs/inputs.py, app/jobs/params.py, or the core)"


def test_the_kind_import_check_sees_an_import(tmp_path):
    """The check above fails on a kind importing another, also inside a function, but not on a
    type-only import."""
    source = tmp_path / "compensate.py"
    source.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                      "    from app.jobs.kinds.probe_plan import ProbePlanParams\n"
                      "def run():\n    from app.jobs.kinds.reconstruct import run\n")
    imports = {"app.jobs.kinds.compensate": _imports(source, "app.jobs.kinds.compensate")}
    assert _kind_imports(imports) == {("compensate", "reconstruct")}


def test_job_kinds_and_their_helpers_never_import_the_database():
    offenders = {(m, i) for m, names in IMPORTS.items() if m.startswith("app.jobs") for i in names
                 if any(i == f or i.startswith(f"{f}.") for f in FORBIDDEN_IN_JOBS)}
    assert offenders == set(), "read through the job's context (app/runtime/reads.py), not the database"


def _session_or_runtime_uses(path: Path) -> set[tuple[str, int]]:
    """(what, line) of every ``.session(...)`` call and ``.runtime`` attribute in ``path``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return {(f".{node.attr}", node.lineno) for node in ast.walk(tree)
            if isinstance(node, ast.Attribute) and node.attr in ("session", "runtime")}


def test_job_kinds_and_their_helpers_never_reach_a_session_or_the_runtime():
    offenders = {(m, *use) for m, path in MODULES.items() if m.startswith("app.jobs")
                 for use in _session_or_runtime_uses(path)}
    assert offenders == set(), "use the named reads and methods of JobContext (app/runtime/context.py)"


def test_the_session_check_sees_a_session_and_the_runtime(tmp_path):
    source = tmp_path / "kind.py"
    source.write_text("def run(ctx):\n    with ctx.session() as s:\n        pass\n"
                      "    ctx.runtime.store.wait()\n    ctx.reads()\n")
    assert _session_or_runtime_uses(source) == {(".session", 2), (".runtime", 4)}


def test_no_import_cycles():
    graph = nx.DiGraph()
    for module, names in IMPORTS.items():
        graph.add_node(module)
        for imported in names:
            target = _internal(imported)
            # a package's __init__ importing its own submodules is how packages re-export
            if target and target != module and not module.startswith(f"{target}.") \
                    and not target.startswith(f"{module}.") and target not in ("app", "hardware"):
                graph.add_edge(module, target)
    cycles = {frozenset(c) for c in nx.simple_cycles(graph) if len(c) > 1}
    assert cycles - KNOWN_CYCLES == set(), "a new import cycle"
    assert KNOWN_CYCLES - cycles == set(), "a known cycle is gone: remove it from KNOWN_CYCLES"


def test_modules_are_small_enough_to_read_in_one_sitting():
    big = {name: n for name, path in MODULES.items() if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES}
    assert big == {}
