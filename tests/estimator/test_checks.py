"""estimator.checks: the one checking layer of SCET's JSON readers. Each refusal is the reader's
InputError naming the file and the dotted key."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from estimator.checks import MAX_JSON_BYTES, Doc, iter_json_lines, load_json, parse_json
from estimator.errors import InputError, SceneError, TrackerInputError


def doc(**fields):
    return Doc(fields, "f.json", error=TrackerInputError)


@pytest.mark.parametrize("value, words", [
    (10 ** 400, "integer too large for a float"),
    (math.nan, "finite number"),
    (math.inf, "finite number"),
    (1e200, "magnitude below"),
    (True, "expected a number, got true"),
    ("1.0", "expected a number, got a string"),
    ([1.0], "expected a number, got a list"),
    (None, "must not be null"),
])
def test_a_number_refuses_what_is_not_a_finite_number(value, words):
    with pytest.raises(TrackerInputError, match=words) as info:
        doc(x_m=value).number("x_m")
    assert str(info.value).startswith("f.json, key 'x_m': ")
    assert info.value.path == "f.json" and info.value.key == "x_m"


def test_a_radius_in_millimetres_under_an_m_key_is_out_of_range():
    with pytest.raises(TrackerInputError, match=r"key 'r_m': expected a value in \[0.001, 0.05\] "
                                                r"\(m; check the unit\), got 7.8"):
        doc(r_m=7.8).number("r_m", lo=1e-3, hi=0.05)
    assert doc(r_m=7.8e-3).number("r_m", lo=1e-3, hi=0.05) == 7.8e-3


def test_nested_keys_and_array_elements_are_named():
    d = doc(a={"b": {"c_m": [0.0, 1.0, "x"]}})
    with pytest.raises(TrackerInputError, match=r"key 'a\.b\.c_m\[2\]': expected a number"):
        d.obj("a").obj("b").array("c_m", (3,))
    with pytest.raises(TrackerInputError, match=r"key 'a\.b\.c_m': expected 2 entries, got 3"):
        d.obj("a").obj("b").array("c_m", (2,))
    with pytest.raises(TrackerInputError, match=r"key 'a': expected an object, got a list"):
        doc(a=[1, 2]).obj("a")
    with pytest.raises(TrackerInputError, match=r"key 'g\[1\]': expected a list of 2"):
        doc(g=[[1, 2], 3]).array("g", (None, 2))


def test_arrays_read_nulls_as_nan_only_when_allowed():
    g = doc(g=[[1, 2], None]).array("g", (None, 2), allow_null=True)
    assert g.shape == (2, 2) and np.isnan(g[1]).all()
    assert doc(g=[]).array("g", (None, 2)).shape == (0, 2)
    with pytest.raises(TrackerInputError, match=r"key 'g\[1\]'"):
        doc(g=[[1, 2], None]).array("g", (None, 2))


def test_integers_strings_and_unknown_keys():
    assert doc(n=3.0).integer("n") == 3
    for bad in (3.5, True, "3", 2 ** 80 + 0.5):
        with pytest.raises(TrackerInputError, match="key 'n': expected an integer"):
            doc(n=bad).integer("n", hi=10)
    with pytest.raises(TrackerInputError, match=r"expected an integer in \[1, 10\], got 0"):
        doc(n=0).integer("n", lo=1, hi=10)
    with pytest.raises(TrackerInputError, match="expected one of"):
        doc(k="x").string("k", choices=("a", "b"))
    with pytest.raises(TrackerInputError, match="key 'zz': unknown key"):
        doc(a=1, zz=2).only(("a",))
    assert doc().integer("n", required=False, default=7) == 7


def test_the_error_type_is_the_readers():
    with pytest.raises(SceneError):
        Doc([], "s.json", error=SceneError)
    assert issubclass(TrackerInputError, InputError) and issubclass(InputError, ValueError)


def test_load_json_refuses_deep_nesting_huge_integers_and_bad_bytes(tmp_path):
    cases = {"deep.json": b"[" * 200_000 + b"]" * 200_000,
             "digits.json": b'{"n": ' + b"1" * 5000 + b"}",
             "latin1.json": '{"name": "é"}'.encode("latin-1"),
             "broken.json": b'{"a": '}
    words = {"deep.json": "nested too deeply", "digits.json": "cannot read JSON",
             "latin1.json": "not UTF-8", "broken.json": "not JSON"}
    for name, raw in cases.items():
        (tmp_path / name).write_bytes(raw)
        with pytest.raises(TrackerInputError, match=words[name]) as info:
            load_json(tmp_path / name, TrackerInputError)
        assert info.value.path == str(tmp_path / name)
    with pytest.raises(TrackerInputError, match="cannot read the file"):
        load_json(tmp_path / "nowhere.json", TrackerInputError)
    with pytest.raises(TrackerInputError, match="cannot read the file"):
        load_json(tmp_path, TrackerInputError)  # a folder


def test_load_json_refuses_a_file_larger_than_a_document_before_reading_it(tmp_path):
    big = tmp_path / "big.json"
    with open(big, "wb") as fh:
        fh.truncate(MAX_JSON_BYTES + 1)  # sparse: no disk, no memory
    with pytest.raises(TrackerInputError, match="more than the"):
        load_json(big, TrackerInputError)


def test_json_lines_name_the_line(tmp_path):
    p = tmp_path / "x.jsonl"
    p.write_text('{"a": 1}\n\n[1, 2\n')
    it = iter_json_lines(p, TrackerInputError)
    assert next(it) == (f"{p}, line 1", {"a": 1})
    with pytest.raises(TrackerInputError, match=r"x\.jsonl, line 3: cannot read JSON"):
        next(it)
    assert parse_json(json.dumps({"a": [1]}), "t") == {"a": [1]}
    p.write_bytes(b'{"a": 1}\n' + b" " * 2000 + b"\n")
    with pytest.raises(TrackerInputError, match=r"line 2: a line of more than 1000 bytes"):
        list(iter_json_lines(p, TrackerInputError, max_line_bytes=1000))
    p.write_bytes(b'{"a": 1}\n{"b": "\xff"}\n')
    with pytest.raises(TrackerInputError, match=r"line 2: not UTF-8"):
        list(iter_json_lines(p, TrackerInputError))
