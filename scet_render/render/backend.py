"""Choose and activate the Mitsuba 3 variant the renderer runs on.

Order of preference (DESIGN.md, "Rendering notes"):

1. ``cuda_ad_rgb`` when an NVIDIA GPU and its driver library are present;
2. ``llvm_ad_rgb`` when a usable libLLVM is found: version 16 or newer. Debian's LLVM 14 and 15
   crash inside Dr.Jit ("Cannot select fminimum"), so they are never picked, not even through
   ``DRJIT_LIBLLVM_PATH``. The library found is exported as ``DRJIT_LIBLLVM_PATH`` before
   Dr.Jit is imported, since Dr.Jit reads it when it first loads LLVM;
3. ``scalar_rgb`` otherwise, with a one-line notice through :mod:`logging` (4-9x slower).

An explicit variant (the CLI's ``--variant``, or the ``SCET_MITSUBA_VARIANT`` environment
variable when none is given) overrides the choice. Mitsuba and Dr.Jit are imported only by
:func:`activate`, so the analytic path of the package never needs them.
"""

from __future__ import annotations

import ctypes.util
import glob
import logging
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

from estimator.errors import InputError

log = logging.getLogger(__name__)


class BackendUnavailableError(InputError):
    """The Mitsuba variant asked for cannot run here (unknown, no GPU for a CUDA variant, no
    usable libLLVM for an LLVM one, or Mitsuba refuses it)."""

#: Oldest libLLVM that Dr.Jit 1.x runs on without crashing (LLVM 14/15 fail, DESIGN.md).
LLVM_MIN_VERSION = 16
#: Variants this package renders with; the RGB channels carry separate light groups.
SUPPORTED_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
#: Environment variable naming a variant when the caller passes none (CI switch).
VARIANT_ENV = "SCET_MITSUBA_VARIANT"
LLVM_ENV = "DRJIT_LIBLLVM_PATH"
#: Where distributions put libLLVM (Debian/Ubuntu multiarch and versioned trees, Fedora,
#: Homebrew). Static archives never match: only shared objects are considered.
DEFAULT_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)

# libLLVM-19.so, libLLVM-19.so.1, libLLVM-14.0.6.so, libLLVM.so.19.1, libLLVM.19.dylib
_VERSION_RE = re.compile(r"^libLLVM(?:-(\d+)(?:\.\d+)*\.so(?:\.\d+)*|\.so\.(\d+)(?:\.\d+)*|"
                         r"\.(\d+)\.dylib)$")


@dataclass(frozen=True, slots=True)
class VariantChoice:
    """The outcome of :func:`choose_variant`.

    Attributes
    ----------
    variant : str
        Mitsuba variant name.
    llvm_path : Path or None
        libLLVM to export as ``DRJIT_LIBLLVM_PATH`` (LLVM variants only).
    reason : str
        One line saying why this variant was chosen.
    """

    variant: str
    llvm_path: Path | None
    reason: str


def llvm_version(path: str | Path) -> int | None:
    """Major version of a libLLVM shared library, read from its file name.

    Unversioned names (``libLLVM.so``) are resolved through their symlink first. Returns None
    when no version can be read.
    """
    p = Path(path)
    for name in (p.name, Path(os.path.realpath(p)).name):
        m = _VERSION_RE.match(name)
        if m:
            return int(next(g for g in m.groups() if g is not None))
    return None


def _usable(path: Path) -> bool:
    version = llvm_version(path)
    return path.is_file() and version is not None and version >= LLVM_MIN_VERSION


def find_libllvm(globs: Sequence[str] | None = None,
                 env: Mapping[str, str] | None = None) -> Path | None:
    """The libLLVM to run the LLVM variants with, or None.

    Parameters
    ----------
    globs : sequence of str, optional
        Shell patterns searched when ``DRJIT_LIBLLVM_PATH`` is unset or unusable (default
        :data:`DEFAULT_LLVM_GLOBS`).
    env : mapping, optional
        Environment to read ``DRJIT_LIBLLVM_PATH`` from (default ``os.environ``).

    Returns
    -------
    Path or None
        ``DRJIT_LIBLLVM_PATH`` when it names an existing libLLVM >= 16; otherwise the newest
        such library matched by ``globs``. Versions 14 and 15 are never returned.
    """
    env = os.environ if env is None else env
    globs = DEFAULT_LLVM_GLOBS if globs is None else globs
    override = env.get(LLVM_ENV)
    if override:
        p = Path(override)
        if _usable(p):
            return p
        log.warning("ignoring %s=%s: not an existing libLLVM >= %d (LLVM 14/15 crash Dr.Jit)",
                    LLVM_ENV, override, LLVM_MIN_VERSION)
    found = []
    for pattern in globs:
        for name in glob.glob(pattern):
            p = Path(name)
            if _usable(p):
                found.append((llvm_version(p), len(p.name), str(p), p))
    if not found:
        return None
    # Newest version; among equal versions the shortest name (the unversioned .so symlink).
    found.sort(key=lambda t: (-t[0], t[1], t[2]))
    return found[0][3]


def gpu_available() -> bool:
    """True when an NVIDIA device node and the CUDA driver library are both present."""
    has_device = bool(glob.glob("/dev/nvidia[0-9]*"))
    return has_device and ctypes.util.find_library("cuda") is not None


def choose_variant(variant: str | None = None, *, globs: Sequence[str] | None = None,
                   env: Mapping[str, str] | None = None,
                   gpu: bool | None = None) -> VariantChoice:
    """Pick the Mitsuba variant (see the module docstring); imports nothing.

    Parameters
    ----------
    variant : str, optional
        ``"auto"`` (same as None) or one of :data:`SUPPORTED_VARIANTS`. None reads
        ``SCET_MITSUBA_VARIANT`` from ``env`` first.
    globs, env
        Passed to :func:`find_libllvm`.
    gpu : bool, optional
        Whether a GPU is present; default :func:`gpu_available`.

    Raises
    ------
    BackendUnavailableError
        For an unknown variant, an LLVM variant asked for while no libLLVM >= 16 exists, or
        the CUDA variant without a GPU.
    """
    env = os.environ if env is None else env
    requested = variant if variant is not None else env.get(VARIANT_ENV) or "auto"
    if requested != "auto" and requested not in SUPPORTED_VARIANTS:
        raise BackendUnavailableError(f"unknown Mitsuba variant {requested!r}: expected 'auto' or one of "
                         f"{', '.join(SUPPORTED_VARIANTS)}")
    llvm = find_libllvm(globs, env) if requested in ("auto", "llvm_ad_rgb") else None
    if requested == "llvm_ad_rgb":
        if llvm is None:
            raise BackendUnavailableError(f"variant llvm_ad_rgb needs libLLVM >= {LLVM_MIN_VERSION} (e.g. "
                             f"apt-get install libllvm19, or set {LLVM_ENV}); none was found")
        return VariantChoice("llvm_ad_rgb", llvm, f"requested; libLLVM {llvm}")
    if requested == "cuda_ad_rgb" and not (gpu_available() if gpu is None else gpu):
        raise BackendUnavailableError("variant cuda_ad_rgb needs an NVIDIA GPU and its CUDA "
                                      "driver library (libcuda); none was found: leave out "
                                      "--variant, or ask for llvm_ad_rgb or scalar_rgb")
    if requested != "auto":
        return VariantChoice(requested, None, "requested")
    if gpu_available() if gpu is None else gpu:
        return VariantChoice("cuda_ad_rgb", None, "NVIDIA GPU found")
    if llvm is not None:
        return VariantChoice("llvm_ad_rgb", llvm, f"libLLVM {llvm}")
    return VariantChoice("scalar_rgb", None,
                         f"no GPU and no libLLVM >= {LLVM_MIN_VERSION} found (install libllvm19 "
                         f"or set {LLVM_ENV}); scalar_rgb is 4-9x slower")


def activate(variant: str | None = None):
    """Choose a variant, point Dr.Jit at libLLVM, import Mitsuba and set the variant.

    Parameters
    ----------
    variant : str, optional
        As in :func:`choose_variant`.

    Returns
    -------
    module
        The ``mitsuba`` module with the variant set (``mi.variant()`` names it).
    """
    choice = choose_variant(variant)
    if choice.llvm_path is not None:
        if "drjit" in sys.modules and os.environ.get(LLVM_ENV) != str(choice.llvm_path):
            # Dr.Jit reads the variable when its LLVM backend starts, on first use, so an
            # earlier import is harmless unless LLVM arrays were already created.
            log.debug("drjit was imported before %s was set", LLVM_ENV)
        os.environ[LLVM_ENV] = str(choice.llvm_path)
    if choice.variant == "scalar_rgb" and variant in (None, "auto") and not os.environ.get(
            VARIANT_ENV):
        log.warning("Mitsuba falls back to scalar_rgb: %s", choice.reason)
    import mitsuba as mi

    if mi.variant() != choice.variant:
        try:
            mi.set_variant(choice.variant)
        except (ImportError, AttributeError, RuntimeError, ValueError) as exc:
            raise BackendUnavailableError(f"Mitsuba cannot run variant {choice.variant} here "
                                          f"({exc})") from None
    log.debug("Mitsuba variant %s (%s)", choice.variant, choice.reason)
    return mi


def is_jit_variant(variant: str) -> bool:
    """True for the Dr.Jit-compiled variants (LLVM, CUDA), False for scalar ones."""
    return variant.startswith(("llvm_", "cuda_"))


# --------------------------------------------------------------------------- LLVM target

#: Dr.Jit's C entry points for the LLVM backend's target (libdrjit-core, C++ linkage: these are
#: the mangled names of jit_llvm_vector_width(), jit_llvm_target_cpu(),
#: jit_llvm_target_features() and jit_llvm_set_target(const char *, const char *, uint32_t)).
_LLVM_SYMBOLS = {"width": "_Z21jit_llvm_vector_widthv", "cpu": "_Z19jit_llvm_target_cpuv",
                 "features": "_Z24jit_llvm_target_featuresv",
                 "set": "_Z19jit_llvm_set_targetPKcS0_j"}


def _drjit_core():
    import drjit

    path = next(Path(drjit.__file__).parent.glob("libdrjit-core*.so*"), None)
    if path is None:
        return None
    try:
        return ctypes.CDLL(str(path))
    except OSError:
        return None


def llvm_target() -> dict | None:
    """The LLVM backend's target: ``cpu``, ``features`` and ``vector_width`` (the lanes every
    compiled kernel uses; rendered bytes depend on it), or None when the backend's target
    cannot be read (another Dr.Jit build, no LLVM variant active)."""
    lib = _drjit_core()
    try:
        width = getattr(lib, _LLVM_SYMBOLS["width"])
        cpu = getattr(lib, _LLVM_SYMBOLS["cpu"])
        features = getattr(lib, _LLVM_SYMBOLS["features"])
    except (AttributeError, TypeError):
        return None
    width.restype = ctypes.c_uint32
    cpu.restype = features.restype = ctypes.c_char_p
    w = int(width())
    if w == 0:
        return None
    return {"cpu": (cpu() or b"").decode(), "features": (features() or b"").decode(),
            "vector_width": w}


def pin_llvm_vector_width(width: int) -> dict:
    """Compile every later kernel ``width`` lanes wide (on this CPU's own target), so that a
    machine whose native width differs renders the bytes of one with ``width``; returns the
    target now in force. Call it before the first kernel is compiled (before the renderer).

    Raises
    ------
    ValueError
        The backend's target cannot be set, or the CPU cannot run kernels that wide.
    """
    now = llvm_target()
    lib = _drjit_core()
    if now is None or lib is None or not hasattr(lib, _LLVM_SYMBOLS["set"]):
        raise ValueError("cannot set the LLVM backend's vector width with this Dr.Jit build")
    if width > now["vector_width"]:
        raise ValueError(f"this CPU ({now['cpu']}) runs LLVM kernels {now['vector_width']} lanes "
                         f"wide, not {width}")
    setter = getattr(lib, _LLVM_SYMBOLS["set"])
    setter.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    setter.restype = None
    setter(now["cpu"].encode(), now["features"].encode(), int(width))
    after = llvm_target()
    if after is None or after["vector_width"] != width:
        raise ValueError(f"the LLVM backend did not take a vector width of {width}")
    return after
