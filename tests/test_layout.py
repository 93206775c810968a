"""The package layout: synthetic data outside the core library, modules and functions of a readable size."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "borescan"

#: the modules that may import :mod:`borescan.synthetic` besides the package itself: the command that
#: writes simulated scans, the planner's device presets (the twin's Yang and demo devices), the papers'
#: reproductions and the discrepancy battery (which draws its cases with the twin)
MAY_IMPORT_SYNTHETIC = {"commands/simulate.py", "commands/plan.py", "discrepancy/battery.py"}

#: modules and functions over the size limits (none today: every module is within them since issue 34);
#: an entry here is a debt with an owner, a new one over a limit fails
MAX_MODULE_LINES, MAX_FUNCTION_LINES = 600, 150
OVERSIZED_MODULES: set[str] = set()
OVERSIZED_FUNCTIONS: set[str] = set()


def _modules() -> list[tuple[str, ast.Module, str]]:
    return [
        (p.relative_to(SRC).as_posix(), ast.parse(p.read_text()), p.read_text())
        for p in sorted(SRC.rglob("*.py"))
    ]


def _imported_modules(tree: ast.Module, rel: str) -> set[str]:
    """Every ``borescan...`` module an import statement names (relative imports resolved)."""
    package = ["borescan", *rel.split("/")[:-1]]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return out


def test_the_core_library_never_imports_synthetic_data():
    offenders = []
    for rel, tree, _ in _modules():
        if rel.startswith(("synthetic/", "papers/")) or rel in MAY_IMPORT_SYNTHETIC:
            continue
        names = _imported_modules(tree, rel)
        bad = sorted(n for n in names if n == "borescan.synthetic" or n.startswith("borescan.synthetic."))
        if bad:
            offenders.append(f"{rel}: {', '.join(bad)}")
    assert not offenders, "the core library imports synthetic data:\n" + "\n".join(offenders)


def test_the_check_sees_every_kind_of_import():
    tree = ast.parse(
        "import borescan.synthetic.scenes\n"
        "from borescan.synthetic import demo\n"
        "from ..synthetic.simulate import simulate_rod\n"
        "from . import rawio\n"
    )
    names = _imported_modules(tree, "stages/measure.py")
    assert {"borescan.synthetic.scenes", "borescan.synthetic.demo", "borescan.synthetic.simulate"} <= names
    assert "borescan.stages.rawio" in names


def test_no_new_module_or_function_over_the_size_limits():
    modules, functions = [], []
    for rel, tree, text in _modules():
        if len(text.splitlines()) > MAX_MODULE_LINES and rel not in OVERSIZED_MODULES:
            modules.append(f"{rel}: {len(text.splitlines())} lines")
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES and f"{rel}:{node.name}" not in OVERSIZED_FUNCTIONS:
                    functions.append(f"{rel}:{node.name}: {n} lines")
    assert not modules, f"modules over {MAX_MODULE_LINES} lines:\n" + "\n".join(modules)
    assert not functions, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(functions)
