"""The estimator's tests run on the base install: none of them imports the renderer's package,
the layer above (``make test-base`` also refuses the import at run time: tests/conftest.py)."""

import ast
from pathlib import Path

LAYER_ABOVE = "scet_render"
#: Calls that import the module named by their first argument.
IMPORT_CALLS = ("importorskip", "import_module", "__import__")


def imported_modules(tree: ast.AST):
    """Every module a parsed file imports: import statements (absolute ones; a relative import
    stays inside tests/estimator) and calls of :data:`IMPORT_CALLS` on a string constant."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and getattr(node.func, "attr", getattr(node.func, "id", None)) in IMPORT_CALLS):
            yield node.args[0].value


def test_no_estimator_test_imports_the_renderer():
    offenders = {}
    for path in sorted(Path(__file__).parent.glob("*.py")):
        names = [name for name in imported_modules(ast.parse(path.read_text(), str(path)))
                 if name == LAYER_ABOVE or name.startswith(LAYER_ABOVE + ".")]
        if names:
            offenders[path.name] = names
    assert not offenders, (f"tests/estimator imports {LAYER_ABOVE} {offenders}: use "
                           "tests/estimator/simulated.py, or move the test to tests/scet_render")
