"""The documentation site's promises, checked from its Markdown sources (no Sphinx build: that
is ``make docs``, warnings as errors, in CI):

- every ``scet`` subcommand appears in the CLI reference (generated from the parser itself by
  sphinx-argparse, so it cannot drift) and is described in the guide's prose;
- every key the scene loader reads, and every key of the built-in scenes, appears in the scene
  format's reference;
- every ``sh`` block of the tutorials runs, line by line, at a small size: ``paper_sim`` is a
  320x240 copy of it, renders are 4 spp with the conductor cornea (as ``scet validate --quick``
  renders), ``work/`` a temporary folder. The worked example block is run by
  ``tests/scet_render/test_workflow.py``; the README's is held to the same lines here. Blocks
  that render many frames (the capture comparison, ``scet validate``) are slow tests.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import io
import re
import shlex
import shutil
import tomllib
from pathlib import Path

import pytest

from estimator.scene import builtin_scenes, resolve_scene
from scet_render.cli import build_parser, main
from tests.scet_render.test_workflow import _small_scene, worked_example

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
TUTORIALS = DOCS / "tutorials"
#: Tutorial blocks that render more than a few frames: (file, first command of the block).
SLOW_BLOCKS = {("compare-capture.md", "scet render"), ("accuracy-regression.md", "scet validate")}


def subcommands(parser: argparse.ArgumentParser) -> list[str]:
    """Every subcommand path of a parser (``"study events"`` for nested ones)."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.append(name)
                out += [f"{name} {inner}" for inner in subcommands(sub)]
    return out


def docs_text(*parts: str) -> str:
    return "\n".join(p.read_text(encoding="utf-8") for part in parts
                     for p in sorted((DOCS / part).rglob("*.md")) if "_build" not in p.parts)


def test_the_cli_reference_is_generated_from_the_parser():
    page = (DOCS / "reference" / "cli.md").read_text(encoding="utf-8")
    assert re.search(r"\.\. argparse::\n\s+:module: scet_render\.cli\n\s+:func: build_parser", page)


def test_every_subcommand_is_described_in_the_guide():
    names = subcommands(build_parser())
    assert {"render", "calibrate", "track", "score", "compare", "validate", "study events"} <= set(names)
    prose = docs_text("guide", "tutorials", "results") + (DOCS / "getting-started.md").read_text()
    missing = [n for n in names if f"scet {n}" not in prose]
    assert missing == []


def _scene_loader_keys() -> set[str]:
    """Keys the scene loader reads (``t.number("key")``, ``t.quantity("base", ...)`` -> base),
    from the source of ``estimator/scene.py`` and ``estimator/eyelids.py``."""
    keys = set()
    for path in (ROOT / "estimator" / "scene.py", ROOT / "estimator" / "eyelids.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in {"string", "integer", "number", "vector", "quantity",
                                           "raw", "table", "has"}
                    and node.args and isinstance(node.args[0], ast.Constant)
                    and isinstance(node.args[0].value, str)):
                keys.add(node.args[0].value)
    return keys


def _builtin_scene_keys() -> set[str]:
    keys = set()

    def walk(d):
        for k, v in d.items():
            keys.add(k)
            if isinstance(v, dict):
                walk(v)
            elif isinstance(v, list) and v and isinstance(v[0], dict):
                for item in v:
                    walk(item)

    for name in builtin_scenes():
        walk(tomllib.loads(resolve_scene(name).read_text(encoding="utf-8")))
    return keys


def test_every_scene_key_is_in_the_scene_reference():
    page = (DOCS / "formats" / "scene.md").read_text(encoding="utf-8")
    documented = {part for name in re.findall(r"`\[*([a-z_.]+)\]*", page)
                  for part in name.split(".")}
    loader = _scene_loader_keys()
    assert {"camera", "focal_px", "exposure", "cornea_asphericity", "blink_rate_per_min"} <= loader

    def found(key: str) -> bool:  # a quantity's base is documented with a unit suffix
        return key in documented or any(d.startswith(key + "_") for d in documented)

    missing = sorted(k for k in loader | _builtin_scene_keys() if not found(k))
    assert missing == []


def test_the_readme_worked_example_is_the_tutorials():
    readme = worked_example(ROOT / "README.md")
    assert readme == worked_example(TUTORIALS / "accuracy-regression.md")
    assert len(readme) == 5


def _blocks(path: Path) -> list[list[str]]:
    text = path.read_text(encoding="utf-8")
    return [[ln for ln in m.group(1).splitlines() if ln.strip()]
            for m in re.finditer(r"^```sh\n(.*?)^```", text, re.S | re.M)]


def _tutorial_blocks(slow: bool):
    """(file, lines) per block; a slow block carries the blocks before it in its file (a
    later block may use what an earlier one wrote)."""
    out = []
    for path in sorted(TUTORIALS.glob("*.md")):
        blocks = _blocks(path)
        if path.name == "accuracy-regression.md":
            blocks = blocks[1:]  # the worked example: tests/scet_render/test_workflow.py
        for i, lines in enumerate(blocks):
            is_slow = (path.name, " ".join(lines[0].split()[:2])) in SLOW_BLOCKS
            if is_slow == slow:
                run = [ln for block in blocks[:i] for ln in block] + lines if slow else lines
                out.append(pytest.param(path.name, run, id=f"{path.stem}-{i}"))
    return out


def test_every_tutorial_has_blocks_and_only_sh_blocks():
    for path in sorted(TUTORIALS.glob("*.md")):
        if path.name == "index.md":
            continue
        fences = re.findall(r"^```(\S*)", path.read_text(encoding="utf-8"), re.M)
        langs = [f for f in fences[::2]]  # opening fences
        assert "sh" in langs, path.name
        assert set(langs) <= {"sh"}, f"{path.name}: blocks that the test would not run: {langs}"


def _run_lines(name: str, lines: list[str], work: Path):
    small = work / "paper_sim_small.toml"
    if not small.exists():
        _small_scene(small)
    for line in lines:
        argv = [str(small) if a == "paper_sim" else a.replace("work/", f"{work}/")
                for a in shlex.split(line)]
        if argv[0] == "cp":
            shutil.copyfile(ROOT / argv[1] if not Path(argv[1]).is_absolute() else argv[1],
                            argv[2])
            continue
        assert argv[0] == "scet", f"{name}: {line}"
        args = argv[1:]
        if args[0] == "render":
            args += [a for a, flag in ((["--spp", "4"], "--spp"), (["--cornea", "conductor"],
                                                                   "--cornea"))
                     if flag not in args for a in a]
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            code = main(args)
        assert code == 0, f"{name}: {line}\n{printed.getvalue()[-2000:]}"


_WORK: dict[str, Path] = {}  # one work folder per tutorial: its blocks run in order


@pytest.mark.parametrize("name, lines", _tutorial_blocks(slow=False))
def test_the_tutorials_run(name, lines, tmp_path_factory):
    if name not in _WORK:
        _WORK[name] = tmp_path_factory.mktemp("tutorial")
    _run_lines(name, lines, _WORK[name])


@pytest.mark.slow
@pytest.mark.parametrize("name, lines", _tutorial_blocks(slow=True))
def test_the_tutorials_that_render_more_run(name, lines, tmp_path_factory):
    _run_lines(name, lines, tmp_path_factory.mktemp("tutorial"))
