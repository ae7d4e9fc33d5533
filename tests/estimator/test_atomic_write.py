"""The one atomic write (estimator.formats): readers see the old file or the whole new one, two
writers of one file never meet in a temporary, a failed write leaves the target as it was."""

from __future__ import annotations

import threading

import pytest

from estimator.formats import PARTIAL_SUFFIX, atomic_file, atomic_write, remove_partials


def test_two_writers_of_one_file_leave_it_whole(tmp_path):
    """Two threads rewrite one file 200 times each with the same 256 kB while a third reads it:
    every read is the whole content (a shared temporary name would interleave the writers)."""
    path = tmp_path / "frame.png"
    data = bytes(range(256)) * 1024
    atomic_write(path, data)
    seen, stop = [], threading.Event()

    def reader():
        while not stop.is_set():
            seen.append(path.read_bytes() == data)

    def writer():
        for _ in range(200):
            atomic_write(path, data)

    threads = [threading.Thread(target=writer) for _ in range(2)]
    r = threading.Thread(target=reader)
    r.start()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stop.set()
    r.join()
    assert seen and all(seen)
    assert [p.name for p in tmp_path.iterdir()] == ["frame.png"]


def test_a_failed_write_keeps_the_old_file_and_removes_its_temporary(tmp_path):
    path = tmp_path / "labels.jsonl"
    atomic_write(path, "old\n")
    with pytest.raises(RuntimeError):
        with atomic_file(path) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("disk full")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == [path.name]


def test_temporaries_are_unique_and_swept(tmp_path):
    names = set()
    for _ in range(3):
        with atomic_file(tmp_path / "x.exr") as tmp:
            names.add(tmp.name)
            tmp.write_bytes(b"1")
    assert len(names) == 3 and all(n.endswith(PARTIAL_SUFFIX) for n in names)
    (tmp_path / f"x.exr.123-4-5{PARTIAL_SUFFIX}").write_bytes(b"killed writer")
    assert remove_partials(tmp_path) == 1 and [p.name for p in tmp_path.iterdir()] == ["x.exr"]
