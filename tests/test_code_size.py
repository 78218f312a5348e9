"""Rooms a newcomer can hold (issue 26): no module of the product packages (``compensation/``,
``protocol/``, ``daemon/``, ``sim_controller/``, ``cli/``) over 600 lines, no function over 80
lines unless its docstring says why ("Long on purpose: …"). Nothing is left out.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = tuple(
    ROOT / name for name in ("compensation", "protocol", "daemon", "sim_controller", "cli")
)
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80
REASON = "long on purpose"


def _modules() -> list[Path]:
    return [
        p
        for package in PACKAGES
        for p in sorted(package.rglob("*.py"))
        if "__pycache__" not in p.parts
    ]


def test_no_module_over_600_lines() -> None:
    long = {
        str(p.relative_to(ROOT)): n
        for p in _modules()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    }
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split them by concept): {long}"


def _long_functions(source: str, where: str) -> dict[str, int]:
    """``{"<where>:<name>": lines}`` of the functions in ``source`` over the limit without a
    reason in their docstring (decorators count)."""
    long: dict[str, int] = {}
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        start = min([node.lineno] + [d.lineno for d in node.decorator_list])
        length = (node.end_lineno or node.lineno) - start + 1
        if length > MAX_FUNCTION_LINES and REASON not in (ast.get_docstring(node) or "").lower():
            long[f"{where}:{node.name}"] = length
    return long


def test_no_function_over_80_lines_without_a_reason() -> None:
    long: dict[str, int] = {}
    for path in _modules():
        long.update(_long_functions(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT))))
    assert not long, (
        f"functions over {MAX_FUNCTION_LINES} lines without '{REASON}: …' in the docstring: {long}"
    )


def test_the_rule_finds_a_long_function_and_accepts_a_reason() -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(80))
    doc = '    """Long on purpose: a test."""\n'
    source = f"@d\ndef f():\n{body}\n\ndef g():\n{doc}{body}\n"
    source += "def h():\n" + "\n".join(f"    y{i} = {i}" for i in range(79)) + "\n"
    assert _long_functions(source, "m.py") == {"m.py:f": 82}
