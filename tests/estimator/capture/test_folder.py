"""Capture folders: written with the one writer, read with the one reader; every bad input the
format can meet gives an error naming the file and key, or a frame slot with a reason."""

import json

import numpy as np
import pytest

from estimator.capture import CaptureError, CaptureFolder, capture_header, write_capture

PERIOD_NS = 16_636_350          # S = 524 lines of 31.74875 us


def make(tmp_path, fmt="SGBRG10_CSI2P", n=5, stride=None, ts=None, rng=None, meta=None, gains=None):
    rng = np.random.default_rng(3) if rng is None else rng
    packed = fmt.endswith("_CSI2P")
    stride = (800 if packed else 1280) if stride is None else stride
    header = capture_header(raw_format=fmt, size_px=(640, 480), stride=stride,
                            camera={"model": "ov5647", "sensor_mode": {"size": [640, 480], "bit_depth": 10}},
                            controls={"FrameDurationLimits": [16637, 16637], "ExposureTime": 984,
                                      "AnalogueGain": 1.0, "AeEnable": False, "AwbEnable": False},
                            strobe=None, software={"test": "1"}, source="test", channel_gains=gains)
    ts = [1_000_000_000 + i * PERIOD_NS for i in range(n)] if ts is None else ts
    images = [rng.integers(16, 1000, (480, 640)).astype(np.uint16) for _ in ts]
    frames = []
    for img, t in zip(images, ts):
        m = {"SensorTimestamp": t, "ExposureTime": 984, "FrameDuration": 16636,
             "AnalogueGain": 1.0, "SensorBlackLevels": [1024, 1024, 1024, 1024]}
        if meta:
            m.update(meta)
        frames.append((img, m))
    write_capture(tmp_path, header, frames)
    return images


@pytest.mark.parametrize("fmt", ["SGBRG10_CSI2P", "SGBRG10"])
def test_round_trip(tmp_path, fmt):
    images = make(tmp_path, fmt)
    cap = CaptureFolder(tmp_path, size_px=(640, 480))
    got = list(cap.frames())
    assert [f.index for f in got] == [0, 1, 2, 3, 4]
    assert all(np.array_equal(f.image, img) for f, img in zip(got, images))
    assert cap.frame_period_s == pytest.approx(PERIOD_NS * 1e-9)
    assert [f.start_s for f in got] == pytest.approx([i * PERIOD_NS * 1e-9 for i in range(5)])
    assert cap.problems == []


def test_black_level_from_metadata(tmp_path):
    # SensorBlackLevels 1280 on the 16-bit scale is 20 DN at 10 bit: 4 DN above the scene's 16.
    images = make(tmp_path, meta={"SensorBlackLevels": [1280] * 4})
    f = next(CaptureFolder(tmp_path).frames())
    assert np.array_equal(f.image.astype(int), np.clip(images[0].astype(int) - 4, 0, 1023))


def test_dropped_frames_leave_reasoned_slots(tmp_path):
    ts = [i * PERIOD_NS for i in (0, 1, 2, 5, 6, 7)]
    make(tmp_path, ts=ts)
    cap = CaptureFolder(tmp_path)
    got = list(cap.frames())
    assert [f.index for f in got] == list(range(8))
    assert [f.index for f in got if f.image is None] == [3, 4] == cap.dropped
    assert "frame 3 dropped (a SensorTimestamp gap): missing" in got[3].reason


@pytest.mark.parametrize("bad, message", [
    ([0, PERIOD_NS, PERIOD_NS, 2 * PERIOD_NS], "line 3: key 'SensorTimestamp' 16636350 repeats"),
    ([0, PERIOD_NS, 500, 2 * PERIOD_NS], "line 3: key 'SensorTimestamp' 500 goes back"),
    ([0, PERIOD_NS, int(2.5 * PERIOD_NS), 3 * PERIOD_NS, 4 * PERIOD_NS], "not on a frame slot"),
])
def test_bad_timestamps_are_left_out_and_named(tmp_path, bad, message):
    make(tmp_path, ts=bad)
    cap = CaptureFolder(tmp_path)
    assert any(message in p and "frames.jsonl" in p for p in cap.problems), cap.problems
    assert sum(f.image is not None for f in cap.frames()) == len(bad) - 1


def test_missing_metadata_key(tmp_path):
    make(tmp_path, n=3)
    path = tmp_path / "frames.jsonl"
    lines = path.read_text().splitlines()
    d = json.loads(lines[1])
    del d["ExposureTime"]
    lines[1] = json.dumps(d)
    path.write_text("\n".join(lines) + "\n")
    cap = CaptureFolder(tmp_path)
    assert cap.problems == [f"{path}, line 2: metadata key 'ExposureTime' missing"]
    got = list(cap.frames())
    assert got[1].image is None and "ExposureTime" in got[1].reason
    assert got[0].image is not None and got[2].image is not None


def test_truncated_frame_is_a_reasoned_slot(tmp_path):
    make(tmp_path, n=3)
    raw = tmp_path / "frames" / "000001.raw"
    raw.write_bytes(raw.read_bytes()[:-100])
    got = list(CaptureFolder(tmp_path).frames())
    assert got[1].image is None
    assert f"{raw}: 383900 bytes, expected 384000 = raw.stride 800 x 480 rows" in got[1].reason
    assert got[2].image is not None


def test_stride_mismatch(tmp_path):
    make(tmp_path, n=2, stride=832)
    head = json.loads((tmp_path / "capture.json").read_text())
    head["raw"]["stride"] = 800
    (tmp_path / "capture.json").write_text(json.dumps(head))
    got = list(CaptureFolder(tmp_path).frames())
    assert all(f.image is None and "expected 384000 = raw.stride 800" in f.reason for f in got)


@pytest.mark.parametrize("edit, message", [
    (lambda h: h["raw"].update(format="SGBRG12_CSI2P"), "key 'raw.format': unknown raw format 'SGBRG12_CSI2P'"),
    (lambda h: h["raw"].update(stride=700), "key 'raw.stride' is 700 bytes, shorter than one SGBRG10_CSI2P row"),
    (lambda h: h["raw"].update(size=[640]), "key 'raw.size' must be"),
    (lambda h: h.update(version=3), "key 'version': this SCET reads scet-capture version one of"),
    (lambda h: h.update(format="scet-dataset"), "key 'format' is 'scet-dataset'"),
    (lambda h: h.update(channel_gains=[1, 1, 0, 1]), "key 'channel_gains'"),
])
def test_bad_headers(tmp_path, edit, message):
    make(tmp_path, n=1)
    head = json.loads((tmp_path / "capture.json").read_text())
    edit(head)
    (tmp_path / "capture.json").write_text(json.dumps(head))
    with pytest.raises(CaptureError, match="capture.json: " + message.replace("(", r"\(").replace("[", r"\[")):
        CaptureFolder(tmp_path)


def test_size_must_match_the_scene(tmp_path):
    make(tmp_path, n=1)
    with pytest.raises(CaptureError, match="raw.size' is 640x480, the scene's camera is 1280x960"):
        CaptureFolder(tmp_path, size_px=(1280, 960))


def test_unpacked_values_above_10_bits(tmp_path):
    make(tmp_path, "SGBRG10", n=1)
    raw = tmp_path / "frames" / "000000.raw"
    data = bytearray(raw.read_bytes())
    data[1] = 0xFF
    raw.write_bytes(bytes(data))
    f = next(CaptureFolder(tmp_path).frames())
    assert f.image is None and "values above 1023" in f.reason


def test_incomplete_folder(tmp_path):
    with pytest.raises(CaptureError, match="no capture.json"):
        CaptureFolder(tmp_path)
