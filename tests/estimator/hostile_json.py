"""Hostile JSON for the readers' fuzz tests: a valid document, mutated by hypothesis the way
tests/estimator/test_scene.py mutates scene files (values that break arithmetic put where
numbers belong, lists where objects belong, deleted and added keys, plausible unit mistakes),
and raw text spliced into the document's bytes."""

from __future__ import annotations

import copy
import json
import math

from hypothesis import strategies as st

#: Values that break readers that trust what they parse.
HAZARDS = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e300, 5e-324, 0, -0.0,
                           10 ** 400, -(10 ** 400), 2 ** 63, True, False, None, "1", "", [], {},
                           [1.0, 2.0], [[1.0]], {"a": 1}, -1, 7.8, 1e-3])
SCALARS = (st.integers(-(2 ** 70), 2 ** 70) | st.floats() | st.text(max_size=8) | st.booleans()
           | st.none())
VALUES = st.recursive(SCALARS, lambda c: st.lists(c, max_size=4)
                      | st.dictionaries(st.text(max_size=6), c, max_size=4), max_leaves=8)
#: Raw text put into a document's bytes: broken structure, deep nesting, huge numbers.
SPLICES = st.sampled_from(["[" * 100_000, "{\"a\":" * 50_000, "1" + "0" * 5000, "NaN", "-Infinity",
                           "\"", "\\", "]", "}", ",", ":", "\ud800", "\x00", "1e999", "null"]) \
    | st.text(max_size=12)


def tree_nodes(node, path=()):
    """(path, value) of every node under a parsed document ``node``, the root excluded."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in items:
        yield path + (k,), v
        yield from tree_nodes(v, path + (k,))


def parent_of(doc, path):
    """The container that holds the node at ``path``."""
    for k in path[:-1]:
        doc = doc[k]
    return doc


def mutated(data, doc: dict) -> dict:
    """``doc`` after one to four random edits drawn from ``data`` (a hypothesis data object)."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 4), label="edits")):
        nodes = list(tree_nodes(doc))
        op = data.draw(st.sampled_from(["poke", "poke", "replace", "scale", "delete", "add"]),
                       label="op")
        if not nodes:
            op = "add"
        if op == "add":
            containers = [doc] + [v for _, v in nodes if isinstance(v, dict)]
            target = data.draw(st.sampled_from(containers), label="object")
            target[data.draw(st.text(max_size=10), label="key")] = data.draw(VALUES, label="value")
            continue
        path, value = data.draw(st.sampled_from(nodes), label="node")
        parent = parent_of(doc, path)
        if op == "delete":
            del parent[path[-1]]
        elif op == "scale" and type(value) in (int, float) and abs(value) < 1e300:
            # Unit mistakes (mm under an _m key), sign flips, zero.
            parent[path[-1]] = value * data.draw(st.sampled_from([1e3, 1e-3, -1.0, 0.0, 1e300]),
                                                 label="factor")
        elif op == "poke":
            parent[path[-1]] = copy.deepcopy(data.draw(HAZARDS, label="hazard"))
        else:
            parent[path[-1]] = data.draw(VALUES, label="value")
    return doc


def hostile_text(data, doc: dict) -> str:
    """JSON text of a mutated ``doc``, or of ``doc`` with raw text spliced in."""
    if data.draw(st.booleans(), label="splice"):
        text = json.dumps(doc)
        start = data.draw(st.integers(0, len(text)), label="start")
        stop = data.draw(st.integers(start, min(len(text), start + 30)), label="stop")
        return text[:start] + data.draw(SPLICES, label="insert") + text[stop:]
    return json.dumps(mutated(data, doc))


def write_text(path, text: str) -> None:
    """Write ``text`` as UTF-8, lone surrogates included (as a hostile writer could)."""
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
