"""Every check in the test suite can fail (issue 34): no ``numpy.testing.assert_*`` call, which returns None, used as
an operand of ``and``/``or`` or inside an ``assert`` (the second check of ``assert_equal(a, b) and c`` never runs),
no ``assert`` whose expression cannot be false, and no comparison or boolean test whose result is thrown away. The
checker reads each file's syntax tree; its own self-test feeds it each bad pattern and a clean file so that it can
fail too."""

import ast
import textwrap
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent

# numpy.testing's checks that return None and raise on failure; imported by name they are recognised as well
NUMPY_CHECKS = {"assert_allclose", "assert_almost_equal", "assert_approx_equal", "assert_array_almost_equal",
                "assert_array_almost_equal_nulp", "assert_array_equal", "assert_array_less", "assert_array_max_ulp",
                "assert_equal", "assert_string_equal", "assert_raises", "assert_warns", "assert_no_warnings"}
# calls whose only use is the truth value they return: as a bare statement they check nothing
BOOLEAN_CALLS = {"allclose", "array_equal", "array_equiv", "isclose", "all", "any", "isfinite", "isnan", "approx"}
_ALWAYS_EQUAL = (ast.Eq, ast.Is, ast.LtE, ast.GtE)            # x op x holds for any x but NaN
# pytest-qt's context managers: called as a bare statement they neither wait nor check anything
CONTEXT_CHECKS = {"waitSignal", "wait_signal", "waitSignals", "wait_signals", "assertNotEmitted", "assert_not_emitted",
                  "waitCallback", "wait_callback", "captureExceptions", "capture_exceptions"}


def _dotted(node):
    """``np.testing.assert_allclose`` -> ["np", "testing", "assert_allclose"]; None for anything but a name chain."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        return [node.id, *reversed(parts)]
    return None


def _imported_checks(tree):
    """The local names under which numpy.testing's checks are imported (``from numpy.testing import x as y``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("testing"):
            names |= {alias.asname or alias.name for alias in node.names if alias.name.startswith("assert_")}
    return names


def _is_none_check(node, imported):
    """A call of a check that returns None: any ``...testing.assert_*`` chain or a numpy check imported by name."""
    if not isinstance(node, ast.Call):
        return False
    chain = _dotted(node.func)
    if chain is None:
        return False
    if len(chain) >= 2 and chain[-2] == "testing" and chain[-1].startswith("assert_"):
        return True
    return len(chain) == 1 and chain[0] in imported | NUMPY_CHECKS


def _always_true(node):
    """An expression that is true whatever the code under test does (a literal, ``x or True``, ``x == x``)."""
    if isinstance(node, ast.Constant):
        return bool(node.value)
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return len(node.elts) > 0
    if isinstance(node, ast.Dict):
        return len(node.keys) > 0
    if isinstance(node, ast.JoinedStr):
        return any(isinstance(v, ast.Constant) and v.value for v in node.values)
    if isinstance(node, (ast.Lambda, ast.GeneratorExp)):
        return True
    if isinstance(node, ast.BoolOp):
        if isinstance(node.op, ast.Or):
            return any(_always_true(v) for v in node.values)
        return all(_always_true(v) for v in node.values)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        return _always_false(node.operand)
    if isinstance(node, ast.Compare) and len(node.ops) == 1 and isinstance(node.ops[0], _ALWAYS_EQUAL):
        left, right = node.left, node.comparators[0]
        return _dotted(left) is not None and ast.dump(left) == ast.dump(right)
    return False


def _always_false(node):
    if isinstance(node, ast.Constant):
        return not node.value
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return len(node.elts) == 0
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        return _always_true(node.operand)
    return False


def problems(source, filename="<snippet>"):
    """Each check in ``source`` that cannot fail, as "file:line: what is wrong"."""
    tree = ast.parse(source, filename=filename)
    imported = _imported_checks(tree)
    found = []

    def flag(node, what):
        found.append(f"{filename}:{node.lineno}: {what}")

    for node in ast.walk(tree):
        if isinstance(node, ast.BoolOp):
            for operand in node.values:
                inner = operand.operand if isinstance(operand, ast.UnaryOp) else operand
                if _is_none_check(inner, imported):
                    flag(inner, "a numpy.testing check (it returns None) used as an operand of and/or: "
                                "the other operand never runs or is never asserted")
        elif isinstance(node, ast.Assert):
            if isinstance(node.test, ast.Tuple) and node.test.elts:
                flag(node, "assert of a tuple, always true: write `assert x, \"message\"`")
            elif _always_true(node.test):
                flag(node, "assert whose expression cannot be false")
            for inner in ast.walk(node.test):
                if _is_none_check(inner, imported):
                    flag(inner, "a numpy.testing check (it returns None) inside an assert: call it on its own line")
        elif isinstance(node, ast.Expr):
            value = node.value
            if isinstance(value, (ast.Compare, ast.BoolOp)) and not any(
                    isinstance(n, ast.Call) and not _returns_truth(n) for n in ast.walk(value)):
                flag(node, "a comparison whose result is thrown away: it asserts nothing")
            elif isinstance(value, ast.Call) and _returns_truth(value):
                flag(node, "a truth test (allclose, all, ...) whose result is thrown away: it asserts nothing")
            elif isinstance(value, ast.Call) and isinstance(value.func, ast.Attribute) \
                    and value.func.attr in CONTEXT_CHECKS:
                flag(node, f"{value.func.attr} called outside `with`: it neither waits nor checks")
    return sorted(set(found), key=lambda line: (line.split(":")[0], int(line.split(":")[1])))


def _returns_truth(call):
    chain = _dotted(call.func)
    if chain is None:
        return isinstance(call.func, ast.Attribute) and call.func.attr in BOOLEAN_CALLS
    return chain[-1] in BOOLEAN_CALLS and chain[0] != "self"


BAD = {
    "and_after_check": "import numpy as np\nnp.testing.assert_array_equal(a, b) and c.all()\n",
    "or_after_check": "import numpy\nc or numpy.testing.assert_allclose(a, b)\n",
    "imported_by_name": "from numpy.testing import assert_allclose as close\nclose(a, b) and c\n",
    "check_in_assert": "import numpy as np\nassert np.testing.assert_allclose(a, b) is None\n",
    "tuple_assert": "assert (x == 1, 'x should be 1')\n",
    "constant_assert": "assert 'always'\n",
    "true_assert": "assert True\n",
    "or_true": "assert x or True\n",
    "same_name": "assert x == x\n",
    "same_attribute": "assert result.rms >= result.rms\n",
    "thrown_away_comparison": "x == 1\n",
    "thrown_away_allclose": "import numpy as np\nnp.allclose(a, b)\n",
    "wait_without_with": "window.open(path)\nqtbot.waitSignal(window.loaded, timeout=10_000)\n",
}

CLEAN = """
import numpy as np
import pytest
from numpy.testing import assert_allclose

def test_clean(a, b, c):
    np.testing.assert_array_equal(a, b)
    assert_allclose(a, b, atol=1e-9)
    assert c.all() and not np.isnan(a).any()
    assert (a == b).all(), "a and b differ"
    assert a == pytest.approx(b)
    assert x == y or x is None
    assert [] == list(c)
    flag = a and b
    ok = np.allclose(a, b)
    assert ok
    with qtbot.waitSignal(window.loaded, timeout=10_000):
        window.open(a)
    blocker = qtbot.waitSignal(window.loaded)
"""


@pytest.mark.parametrize("name", sorted(BAD))
def test_the_checker_flags_each_pattern_that_cannot_fail(name):
    source = BAD[name]
    found = problems(source, f"{name}.py")
    last = len(source.strip().splitlines())
    assert found and all(line.startswith(f"{name}.py:{last}:") for line in found), found


def test_the_checker_passes_checks_that_can_fail():
    assert problems(textwrap.dedent(CLEAN)) == []


def test_no_check_in_the_suite_cannot_fail():
    files = sorted(TESTS.rglob("*.py"))
    assert len(files) > 50                                          # the whole tree was read, not an empty glob
    found = [line for path in files for line in problems(path.read_text(encoding="utf-8"),
                                                         str(path.relative_to(TESTS.parent)))]
    assert found == [], "\n".join(found)
