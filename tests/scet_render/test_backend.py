"""Mitsuba variant selection: libLLVM search, GPU/LLVM/scalar order, overrides, activation."""

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from scet_render.render import (
    LLVM_ENV,
    VARIANT_ENV,
    choose_variant,
    find_libllvm,
    is_jit_variant,
    llvm_version,
)

REPO = Path(__file__).resolve().parents[2]


def _touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x7fELF")
    return path


@pytest.mark.parametrize("name, version", [
    ("libLLVM-19.so", 19), ("libLLVM-15.so.1", 15), ("libLLVM-14.0.6.so", 14),
    ("libLLVM.so.19.1", 19), ("libLLVM.so.18", 18), ("libLLVM.17.dylib", 17),
    ("libLLVM.so", None), ("libLLVMX86CodeGen.a", None), ("libLLVMCore.so.19", None),
])
def test_llvm_version_from_file_name(name, version):
    assert llvm_version(name) == version


def test_unversioned_name_resolves_through_its_symlink(tmp_path):
    real = _touch(tmp_path / "libLLVM.so.18.1")
    (tmp_path / "libLLVM.so").symlink_to(real.name)
    assert llvm_version(tmp_path / "libLLVM.so") == 18
    assert find_libllvm([str(tmp_path / "libLLVM.so")], env={}) == tmp_path / "libLLVM.so"


def test_search_picks_the_newest_usable_and_never_14_or_15(tmp_path):
    for name in ("libLLVM-14.so.1", "libLLVM-15.so", "libLLVM-15.so.1", "libLLVMCore.a"):
        _touch(tmp_path / "multiarch" / name)
    globs = [str(tmp_path / "multiarch" / "libLLVM*.so*"), str(tmp_path / "llvm-*/lib/libLLVM*")]
    assert find_libllvm(globs, env={}) is None  # only the crashing versions are installed
    _touch(tmp_path / "llvm-17" / "lib" / "libLLVM-17.so")
    _touch(tmp_path / "multiarch" / "libLLVM-19.so")
    _touch(tmp_path / "multiarch" / "libLLVM.so.19.1")
    # The newest version; of its two names the shorter (the unversioned -19.so link).
    assert find_libllvm(globs, env={}) == tmp_path / "multiarch" / "libLLVM-19.so"


def test_environment_variable_wins_when_usable(tmp_path, caplog):
    newest = _touch(tmp_path / "libLLVM-19.so")
    pinned = _touch(tmp_path / "pinned" / "libLLVM-16.so")
    globs = [str(tmp_path / "libLLVM*.so*")]
    assert find_libllvm(globs, env={LLVM_ENV: str(pinned)}) == pinned
    old = _touch(tmp_path / "old" / "libLLVM-15.so")
    with caplog.at_level(logging.WARNING, logger="scet_render.render.backend"):
        # An LLVM 15 (crashes Dr.Jit) or a missing file is ignored, with a warning.
        assert find_libllvm(globs, env={LLVM_ENV: str(old)}) == newest
        assert find_libllvm(globs, env={LLVM_ENV: str(tmp_path / "gone.so")}) == newest
    assert sum("ignoring DRJIT_LIBLLVM_PATH" in r.message for r in caplog.records) == 2


def test_variant_order_gpu_then_llvm_then_scalar(tmp_path):
    llvm = _touch(tmp_path / "libLLVM-18.so")
    with_llvm, without = [str(tmp_path / "libLLVM*.so*")], [str(tmp_path / "none*")]
    assert choose_variant(globs=with_llvm, env={}, gpu=True).variant == "cuda_ad_rgb"
    choice = choose_variant(globs=with_llvm, env={}, gpu=False)
    assert (choice.variant, choice.llvm_path) == ("llvm_ad_rgb", llvm)
    choice = choose_variant(globs=without, env={}, gpu=False)
    assert (choice.variant, choice.llvm_path) == ("scalar_rgb", None)
    assert "libllvm19" in choice.reason  # the notice says how to get the fast variant


def test_overrides_and_bad_names(tmp_path):
    without = [str(tmp_path / "none*")]
    assert choose_variant("scalar_rgb", globs=without, env={}, gpu=True).variant == "scalar_rgb"
    assert choose_variant("auto", globs=without, env={}, gpu=False).variant == "scalar_rgb"
    env = {VARIANT_ENV: "scalar_rgb"}
    assert choose_variant(None, globs=without, env=env, gpu=True).variant == "scalar_rgb"
    with pytest.raises(ValueError, match="unknown Mitsuba variant 'llvm_rgb'"):
        choose_variant("llvm_rgb", globs=without, env={})
    with pytest.raises(ValueError, match="needs libLLVM >= 16"):
        choose_variant("llvm_ad_rgb", globs=without, env={})
    assert is_jit_variant("llvm_ad_rgb") and is_jit_variant("cuda_ad_rgb")
    assert not is_jit_variant("scalar_rgb")


def _run(code: str, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=120)


def test_activate_exports_the_library_before_drjit_loads_it():
    pytest.importorskip("mitsuba")
    if find_libllvm() is None:
        pytest.skip("no libLLVM >= 16 on this machine: the LLVM variant cannot be activated")
    env = {k: v for k, v in os.environ.items() if k not in (LLVM_ENV, VARIANT_ENV)}
    code = ("import os, sys\n"
            "from scet_render.render.backend import activate\n"
            "assert 'drjit' not in sys.modules  # the analytic path never imports it\n"
            "mi = activate()\n"
            "print(mi.variant(), os.environ['DRJIT_LIBLLVM_PATH'])\n")
    out = _run(code, env)
    assert out.returncode == 0, out.stderr
    variant, path = out.stdout.split()
    assert variant in ("llvm_ad_rgb", "cuda_ad_rgb") and llvm_version(path) >= 16


def test_scalar_fallback_logs_one_notice():
    pytest.importorskip("mitsuba")
    env = {k: v for k, v in os.environ.items() if k not in (LLVM_ENV, VARIANT_ENV)}
    code = ("import logging\n"
            "logging.basicConfig(level=logging.WARNING, format='%(name)s|%(message)s')\n"
            "import scet_render.render.backend as b\n"
            "b.DEFAULT_LLVM_GLOBS = ()\n"
            "b.gpu_available = lambda: False\n"
            "print(b.activate().variant())\n")
    out = _run(code, env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["scalar_rgb"]
    notices = [line for line in out.stderr.splitlines() if line.startswith("scet_render.render.backend|")]
    assert len(notices) == 1 and "scalar_rgb" in notices[0]
