"""Find a libLLVM that Dr.Jit's LLVM backend can use, before ``drjit`` is imported.

Dr.Jit 1.5 aborts the whole process ("LLVM ERROR: Cannot select ... fminimum") when it
JIT-compiles with libLLVM 15 or 16, which is what Debian 12 ships by default. libLLVM >= 17
works. This module looks for one, points ``DRJIT_LIBLLVM_PATH`` at it and otherwise raises an
``ImportError`` that says what to install, so that a user never meets the abort.
"""
from __future__ import annotations

import glob
import os
import re

MIN_LLVM_MAJOR = 17

_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)

INSTALL_HINT = (
    "install it with `apt-get install -y libllvm19` (Debian/Ubuntu; any libLLVM >= 17 works) "
    "or point DRJIT_LIBLLVM_PATH at one"
)


def llvm_major_version(path: str) -> int | None:
    """Major LLVM version encoded in a library file name, e.g. ``libLLVM-19.so`` -> 19.

    Returns ``None`` when the name carries no version (e.g. a bare ``libLLVM.so``).
    """
    name = os.path.basename(path)
    m = re.search(r"libLLVM[-.]?(\d+)", name) or re.search(r"libLLVM\.so\.(\d+)", name)
    if m is None:
        m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm(candidates: list[str] | None = None) -> str | None:
    """Newest libLLVM with major version >= ``MIN_LLVM_MAJOR`` among ``candidates``.

    ``candidates`` defaults to the usual system locations. Returns its path or ``None``.
    """
    if candidates is None:
        candidates = sorted({p for g in _SEARCH_GLOBS for p in glob.glob(g)})
    best: tuple[int, str] | None = None
    for path in candidates:
        major = llvm_major_version(path)
        if major is None or major < MIN_LLVM_MAJOR or not os.path.exists(path):
            continue
        if best is None or major > best[0]:
            best = (major, path)
    return None if best is None else best[1]


def ensure_libllvm(*, required: bool = True) -> str | None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a usable libLLVM and return it, or raise ``ImportError``.

    A path the user already set is honoured when it exists and is not a known-bad version.
    ``required=False`` (a CUDA variant was asked for): return ``None`` when none is found;
    Dr.Jit then runs without its LLVM backend (a bad libLLVM is still never loaded).
    """
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    if user:
        major = llvm_major_version(user)
        if not os.path.exists(user):
            raise ImportError(f"DRJIT_LIBLLVM_PATH={user} does not exist; {INSTALL_HINT}")
        if major is not None and major < MIN_LLVM_MAJOR:
            raise ImportError(
                f"DRJIT_LIBLLVM_PATH={user} is LLVM {major}; Dr.Jit aborts with LLVM < "
                f"{MIN_LLVM_MAJOR}: {INSTALL_HINT}")
        return user
    path = find_libllvm()
    if path is None and not required:
        os.environ["DRJIT_LIBLLVM_PATH"] = os.devnull   # never the system's libLLVM 15/16
        return None
    if path is None:
        raise ImportError(
            f"lidar_mitsuba needs libLLVM >= {MIN_LLVM_MAJOR} for Dr.Jit's LLVM backend "
            f"(15/16 abort the process); {INSTALL_HINT}")
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path
