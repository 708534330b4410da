"""The code's shape, by an AST count (issue 43): no public function takes more than
seven parameters (a run's setting travels as one value: :class:`cipcore.scenario.Scenario`,
:class:`validation.run.RunSetting`, ...), and no function runs past 80 lines without
saying why in its docstring ("... is long because ..." or "... is long for a reason: ...").

Private modules (``reduced/_kernels.py`` and the like: numba kernels, which take arrays
and scalars since numba cannot take a dataclass) and functions nested in others are not
public.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cipcore", "cip", "reduced", "validation")
MAX_PARAMS = 7
MAX_LINES = 80
REASON = re.compile(r"is long (because|for a reason)")


def _functions():
    """(path, function node, is_public) for every function in the packages, nested ones
    marked private."""
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text())
            private_module = path.stem.startswith("_") and path.stem != "__init__"
            nested: set[int] = set()
            for node in ast.walk(tree):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    for inner in ast.walk(node):
                        if inner is not node and isinstance(
                            inner, ast.FunctionDef | ast.AsyncFunctionDef
                        ):
                            nested.add(id(inner))
            for node in ast.walk(tree):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    public = not (private_module or node.name.startswith("_") or id(node) in nested)
                    yield path.relative_to(ROOT), node, public


def _n_params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    return len(names) - (1 if names and names[0] in ("self", "cls") else 0)


def test_no_public_function_takes_more_than_seven_parameters():
    wide = [
        f"{path}:{fn.lineno} {fn.name} ({_n_params(fn)})"
        for path, fn, public in _functions()
        if public and _n_params(fn) > MAX_PARAMS
    ]
    assert not wide, "public functions over 7 parameters:\n" + "\n".join(wide)


def test_no_long_function_without_a_reason():
    long = [
        f"{path}:{fn.lineno} {fn.name} ({fn.end_lineno - fn.lineno + 1} lines)"
        for path, fn, _ in _functions()
        if fn.end_lineno - fn.lineno + 1 > MAX_LINES
        and not REASON.search(" ".join((ast.get_docstring(fn) or "").split()))
    ]
    assert not long, "functions over 80 lines without a reason in the docstring:\n" + "\n".join(
        long
    )


def test_the_count_sees_a_wide_function(tmp_path):
    """The parameter count itself: a method's self is not counted, keyword-only ones are."""
    src = "def f(self, a, b, *, c, d, e, f, g, h): pass\n"
    (fn,) = [n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.FunctionDef)]
    assert _n_params(fn) == 8
