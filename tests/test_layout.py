"""The packages' layout rules (README "Layout and conventions"), read from the source with ``ast``:

- no import circles between modules;
- imports run down the layers below, never up (the estimator never reaches the renderer);
- nothing outside a subpackage imports a private (``_name``) name or module from inside it, or
  reaches into a private attribute (``obj._name``) that only modules outside its own subpackage
  (its own module, for a top-level one) define;
- every subpackage has a face (``__init__.py`` with ``__all__``) that names only what it
  re-exports, and no module is over 500 lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("estimator", "scet_render", "hardware")
#: Installed names of packages whose folder has another name (pyproject.toml package-dir).
INSTALLED_AS = {"hardware": "scet_hardware"}

#: Layers, lowest first: a module may import from its own layer and the ones before it. The
#: first dotted part under the package names the layer (a subpackage or a top-level module).
LAYERS = {
    "estimator": [
        {"errors", "checks", "formats", "reasons", "jitcache"},
        {"geometry", "lens"},
        {"eye", "setup"},
        {"eyelids", "lens_keys", "scene_checks", "scene_wire"},
        {"scene", "banding", "metrics"},
        {"cornea"},
        {"calibration"},
        {"gaze"},
        {"glints", "capture"},
        {"matching"},
        {"tracking", "tracker"},
        {"inputs", "folders", "events"},
        {"live"},
    ],
    "scet_render": [
        {"render", "motion", "cluster"},
        {"simulate", "band_diagram"},
        {"dataset"},
        {"validate", "reproduce", "design", "study", "compare"},
        {"cli", "cli_data", "cli_progress", "cli_scene", "cli_studies", "cli_camera", "runner", "__main__"},
    ],
    "hardware": [
        {"firmware", "mirror", "board"},
        {"profiles", "strobe_protocol", "strobe", "lock", "capture"},
        {"cli", "cli_run"},
    ],
}
#: What each package may import of the other packages and heavy libraries.
FORBIDDEN = {
    "estimator": ("scet_render", "scet_hardware", "hardware", "mitsuba", "drjit", "OpenEXR",
                  "trimesh"),
    # The prototype's code runs on the Pi beside the estimator: never the renderer, except the
    # `scet hardware` subcommand's module, which plugs into scet's CLI (its flag checks).
    "hardware": ("scet_render", "mitsuba", "drjit", "OpenEXR", "trimesh"),
}
#: Modules allowed one of their package's FORBIDDEN imports, and which: the mirror's STL
#: export (trimesh, imported when a mesh is written, on the desktop that prints the part).
FORBIDDEN_EXCEPT = {"hardware.cli": {"scet_render"}, "hardware.mirror": {"trimesh"}}
MAX_LINES = 500


def _modules():
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            mods[name] = path
    return mods


MODULES = _modules()


def _imports(name: str, path: Path):
    """(imported module or name, line) for every import in the module, lazy ones included."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                parent = base[: len(base) - node.level + 1]
                target = ".".join(parent + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                yield target, alias.name, node.lineno
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, None, node.lineno


def _edges():
    edges = {m: set() for m in MODULES}
    for m, path in MODULES.items():
        for target, name, _ in _imports(m, path):
            for t in (target, f"{target}.{name}" if name else None):
                if t in MODULES and t != m:
                    edges[m].add(t)
    return edges


def _layer(module: str) -> tuple[str, int] | None:
    parts = module.split(".")
    pkg = parts[0]
    if pkg not in LAYERS or len(parts) == 1:
        return None
    for rank, names in enumerate(LAYERS[pkg]):
        if parts[1] in names:
            return pkg, rank
    raise AssertionError(f"{module}: no layer in tests/test_layout.py LAYERS; give it one")


def test_there_are_modules_to_check():
    assert len(MODULES) > 60


def test_no_import_circles():
    edges = _edges()
    index, low, stack, on, cycles = {}, {}, [], set(), []
    counter = [0]

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
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
                cycles.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    assert cycles == []


def test_imports_run_down_the_layers():
    up = []
    for m, path in MODULES.items():
        src = _layer(m)
        for target, name, line in _imports(m, path):
            root = target.split(".")[0]
            for bad in FORBIDDEN.get(m.split(".")[0], ()):
                if root == bad and bad not in FORBIDDEN_EXCEPT.get(m, ()):
                    up.append(f"{m}:{line} imports {target}")
            dst = _layer(target) if target.split(".")[0] == m.split(".")[0] else None
            if src and dst and dst[1] > src[1]:
                up.append(f"{m}:{line} imports {target} (layer {dst[1]} above {src[1]})")
    assert up == []


def _subpackage(module: str) -> str | None:
    """The subpackage (``pkg.sub``) a module belongs to, or None for a top-level module."""
    parts = module.split(".")
    if len(parts) >= 2 and (ROOT / parts[0] / parts[1] / "__init__.py").is_file():
        return ".".join(parts[:2])
    return None


@pytest.mark.parametrize("pkg", PACKAGES)
def test_no_private_name_crosses_a_subpackage_border(pkg):
    crossing = []
    for m, path in MODULES.items():
        if not m.startswith(pkg):
            continue
        for target, name, line in _imports(m, path):
            home = _subpackage(target) if target.split(".")[0] in PACKAGES else None
            if home is None or home == _subpackage(m):
                continue
            private_module = any(p.startswith("_") for p in target.split("."))
            if private_module or (name and name.startswith("_")):
                crossing.append(f"{m}:{line} imports {name} from {target}")
    assert crossing == []


def test_every_subpackage_has_a_face():
    for init in sorted(p for pkg in PACKAGES for p in (ROOT / pkg).glob("*/__init__.py")):
        tree = ast.parse(init.read_text(encoding="utf-8"))
        assert ast.get_docstring(tree), f"{init}: no docstring"
        names = [n for n in tree.body if isinstance(n, ast.Assign)
                 and any(isinstance(t, ast.Name) and t.id == "__all__" for t in n.targets)]
        assert names, f"{init}: no __all__"
        exported = {e.value for e in names[0].value.elts}
        imported = {a.asname or a.name for n in tree.body if isinstance(n, ast.ImportFrom)
                    for a in n.names}
        assert exported <= imported, f"{init}: __all__ names {exported - imported} it does not import"


def test_modules_stay_small():
    big = {m: n for m, p in MODULES.items()
           if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert big == {}


def test_every_package_is_installed():
    """pyproject.toml lists every package and subpackage (setuptools installs only those)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    present = {INSTALLED_AS.get(m.split(".")[0], m.split(".")[0]) + m[len(m.split(".")[0]):]
               for m, p in MODULES.items() if p.name == "__init__.py"}
    assert present - listed == set()


#: Private attributes of other libraries' public API (namedtuple's, sys's, os's).
FOREIGN_PRIVATE = {"_replace", "_asdict", "_fields", "_make", "_field_defaults", "_getframe",
                   "_exit"}


def _defined_names(path: Path) -> set:
    """Every name a module defines or binds: functions, classes, assigned names and
    attributes (``self._x = ...``), annotated fields, arguments and imports."""
    names = set()
    for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(n.name)
        elif isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store):
            names.add(n.attr)
        elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store):
            names.add(n.id)
        elif isinstance(n, ast.arg):
            names.add(n.arg)
        elif isinstance(n, ast.alias):
            names.add(n.asname or n.name.split(".")[-1])
    return names


def _home(module: str) -> str:
    """The unit of privacy of a module: its subpackage, or the module itself."""
    return _subpackage(module) or module


@pytest.mark.parametrize("pkg", PACKAGES)
def test_no_private_attribute_is_reached_across_a_border(pkg):
    """``obj._name`` (an attribute, not an import) where no module of the reader's own
    subpackage (its own module, for a top-level module) defines ``_name``: it reads a private
    of another module through an object (``tracker._state`` from another module)."""
    defined = {}
    for m, path in MODULES.items():
        defined.setdefault(_home(m), set()).update(_defined_names(path))
    reached = []
    for m, path in MODULES.items():
        if not m.startswith(pkg):
            continue
        own = defined[_home(m)]
        for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(n, ast.Attribute) and n.attr.startswith("_") \
                    and not n.attr.startswith("__") and n.attr not in FOREIGN_PRIVATE \
                    and n.attr not in own:
                reached.append(f"{m}:{n.lineno} reads {ast.unparse(n)}")
    assert reached == []


def test_a_reach_in_is_caught(tmp_path):
    """The reach-in check sees what it is for: a private attribute set in one module and read
    through an object in another."""
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("class T:\n    def __init__(self):\n        self._state = 1\n")
    b.write_text("def f(tracker):\n    return tracker._state, tracker.public\n")
    reads = [n.attr for n in ast.walk(ast.parse(b.read_text())) if isinstance(n, ast.Attribute)
             and n.attr.startswith("_") and n.attr not in _defined_names(b)]
    assert "_state" in _defined_names(a) and reads == ["_state"]
