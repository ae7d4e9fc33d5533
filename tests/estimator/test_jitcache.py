"""estimator.jitcache: Numba's cached kernels go when any Numba source changes."""

from __future__ import annotations

from estimator import jitcache


def _tree(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "__pycache__").mkdir()
    (tmp_path / "a" / "kernel.py").write_text("import numba\n")
    (tmp_path / "a" / "plain.py").write_text("x = 1\n")
    return tmp_path


def _cache(root):
    for name in ("kernel.f-1.py311.nbi", "kernel.f-1.py311.nbc"):
        (root / "a" / "__pycache__" / name).write_bytes(b"old")


def test_an_edited_kernel_source_clears_every_cached_kernel(tmp_path):
    root = _tree(tmp_path)
    _cache(root)
    assert jitcache.refresh(root)  # first run: no stamp yet, the cache may be stale
    assert not list(root.rglob("*.nb?"))
    _cache(root)
    assert not jitcache.refresh(root)  # nothing changed: the cache stays
    assert len(list(root.rglob("*.nb?"))) == 2
    (root / "a" / "plain.py").write_text("x = 2\n")  # no Numba in it: no effect
    assert not jitcache.refresh(root)
    (root / "a" / "kernel.py").write_text("import numba\n# edited\n")
    assert jitcache.refresh(root)
    assert not list(root.rglob("*.nb?"))


def test_the_package_is_stamped_after_import():
    import estimator

    root = __import__("pathlib").Path(estimator.__file__).parent
    stamp = root / jitcache.STAMP
    assert stamp.read_text().strip() == jitcache.sources_digest(root)
