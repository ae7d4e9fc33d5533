"""``scet bands --measure``: the table, the JSON keys of issue 13, and bad input."""

import json

from scet_render.cli import main
from tests.estimator.capture.banded import make_capture


def test_bands_measure_writes_the_issue_keys(tmp_path, capsys):
    make_capture(tmp_path / "c", S=524, ppm=-300.0, frames=6)
    assert main(["bands", "--measure", str(tmp_path / "c"), "--json", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "total lines S" in out and "strobe clock" in out
    doc = json.loads((tmp_path / "m.json").read_text())
    for key in ("total_lines", "exposure_s", "pulse_s", "phase_s", "clock_ppm"):
        assert key in doc and key + "_sd" in doc
    assert len(doc["phase_s"]) == len(doc["phase_s_sd"]) == 6
    assert abs(doc["total_lines"] - 524) < 0.5 and abs(doc["clock_ppm"] + 300) < 20


def test_bands_measure_of_no_capture_is_one_line(tmp_path, capsys):
    assert main(["bands", "--measure", str(tmp_path)]) == 2
    assert "no capture.json" in capsys.readouterr().err
