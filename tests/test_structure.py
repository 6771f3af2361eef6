"""The house rules a reader relies on, read from the source: no function over 60 lines outside the
compiled kernels, no module importing another's private names, no test module importing another,
the bus code in one place."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from .processes import ROOT

LONGEST = 60  # lines of a function; a compiled kernel may be longer (one loop the compiler sees whole)
KERNEL_DECORATORS = ("njit", "jit", "cuda.jit", "vectorize", "guvectorize")


def sources(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py"))


def is_kernel(function: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    names = [ast.unparse(d.func if isinstance(d, ast.Call) else d) for d in function.decorator_list]
    return any(name.split(".", 1)[-1] in KERNEL_DECORATORS or name in KERNEL_DECORATORS for name in names)


def long_functions(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not is_kernel(node):
            lines = (node.end_lineno or node.lineno) - node.lineno + 1
            if lines > LONGEST:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    return found


def test_no_function_is_over_60_lines_outside_the_compiled_kernels():
    found = [f for path in sources("services", "spikinglab", "examples") for f in long_functions(path)]
    assert not found, found


def test_no_module_imports_another_modules_private_names():
    found = []
    for path in sources("services", "spikinglab", "examples", "tests"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                private = [a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
                if private:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.module}: {private}")
    assert not found, found


def imported_modules(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
    return found


def test_only_the_bus_package_imports_zenoh():
    """docs/bus.md: outside services/bus/ no module imports zenoh (tests forge messages with their own sessions)."""
    bus = ROOT / "services" / "bus"
    found = [
        f"{path.relative_to(ROOT)}:{line} {module}"
        for path in sources("services", "spikinglab", "examples")
        if bus not in path.parents
        for line, module in imported_modules(path)
        if module.split(".")[0] == "zenoh"
    ]
    assert not found, found


@pytest.mark.parametrize("path", sources("tests"), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_test_module_imports_another(path):
    """Shared helpers live in modules that are not tests (processes.py, launching.py, ...)."""
    imported = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            modules = [node.module or ""] + [f"{node.module or ''}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        else:
            continue
        imported += [m for m in modules if any(part.startswith("test_") for part in m.split("."))]
    assert not imported, f"{path.relative_to(ROOT)} imports test modules: {imported}"
