"""The renderer, set up on first use: a usable libLLVM for Dr.Jit (:mod:`.libllvm`), the
Mitsuba variant (``LIDAR_MITSUBA_VARIANT``, default ``llvm_ad_mono``) and the plugins
(``lidar_mitsuba_plugins``, the top-level ``plugins/`` folder), which register themselves in
every variant that becomes active.

Nothing here imports Mitsuba or Dr.Jit at import time: :func:`ensure_renderer` does, once, the
first time a trace module (``trace/scene.py``, ``materials.py``, ``pilot.py``) is imported or a
run starts. The pure stages (ground, detector, products) never need it.
"""
from __future__ import annotations

import os
import sys
import threading

from . import syntax
from .libllvm import ensure_libllvm

DEFAULT_VARIANT = "llvm_ad_mono"
SUPPORTED_VARIANTS = ("llvm_ad_mono", "cuda_ad_mono", "llvm_ad_rgb", "cuda_ad_rgb")


def usable_variants() -> list[str]:
    """The supported variants this machine can run: CUDA ones only where a GPU is found, LLVM
    ones only where a usable libLLVM was (the renderer's set-up under a CUDA variant points
    Dr.Jit at ``os.devnull`` when it finds none)."""
    import mitsuba as mi
    return [v for v in SUPPORTED_VARIANTS if v in mi.variants() and _has_backend(v)]


def _has_backend(name: str) -> bool:
    """Whether the backend of JIT variant ``name`` can run here."""
    import drjit as dr
    if name.startswith("cuda"):
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    return os.environ.get("DRJIT_LIBLLVM_PATH") != os.devnull


def set_variant(name: str = DEFAULT_VARIANT) -> str:
    """Activate Mitsuba variant ``name`` (e.g. ``llvm_ad_mono``, ``cuda_ad_mono``).

    Use one variant per process where you can: objects (scenes, BSDFs) made in another variant
    of the same backend must be released before tracing in this one.

    Raises ``ValueError`` naming the variant when it is unknown or its backend is absent (no
    CUDA GPU, or no usable libLLVM).
    """
    if "drjit" not in sys.modules:          # the first use: libLLVM before Dr.Jit loads
        ensure_libllvm(required=not name.startswith("cuda"))
    with syntax.deferred():                 # Mitsuba's and our plugins' @dr.syntax
        return _set_variant(name)


def _set_variant(name: str) -> str:
    import mitsuba as mi
    import lidar_mitsuba_plugins
    usable = usable_variants()
    if name.startswith("scalar"):
        raise ValueError(f"variant {name!r} is not supported: use a JIT variant such as "
                         f"{DEFAULT_VARIANT}")
    if name in mi.variants() and not _has_backend(name):
        raise ValueError(f"variant {name!r} needs a CUDA GPU and driver, and none was found "
                         f"(use llvm_ad_mono on the CPU)" if name.startswith("cuda") else
                         f"variant {name!r} needs libLLVM >= 17, and none was found (this "
                         f"process runs a CUDA variant only)")
    if name not in usable:
        raise ValueError(f"variant {name!r} is not available (choose from {', '.join(usable)})")
    if mi.variant() != name:
        mi.set_variant(name)
    lidar_mitsuba_plugins.register(name)
    return name


class RendererUnavailable(ImportError):
    """No usable libLLVM or variant: one line that says what to install or choose (an
    ``ImportError``, as the import-time refusal it replaces)."""


_ready = False
_lock = threading.Lock()


def ensure_renderer():
    """Set the renderer up, once: a usable libLLVM before Dr.Jit loads (unless a CUDA variant
    is asked for), ``LIDAR_MITSUBA_VARIANT`` (default ``llvm_ad_mono``) unless a variant is
    active, and the plugins in it and in every later one. Returns the ``mitsuba`` module;
    cheap after the first call, thread-safe.

    >>> mi = ensure_renderer()          # doctest: +SKIP
    >>> mi.variant()                    # doctest: +SKIP
    'llvm_ad_mono'

    Raises:
        RendererUnavailable: no usable libLLVM (with what to install), or an unknown or
            unusable ``LIDAR_MITSUBA_VARIANT``.
    """
    global _ready
    if _ready:
        return sys.modules["mitsuba"]
    with _lock:
        if not _ready:
            wanted = os.environ.get("LIDAR_MITSUBA_VARIANT") or DEFAULT_VARIANT
            if "drjit" not in sys.modules:   # too late to steer Dr.Jit once it is loaded
                try:
                    ensure_libllvm(required=not wanted.startswith("cuda"))
                except ImportError as e:
                    raise RendererUnavailable(str(e)) from None
            with syntax.deferred():    # @dr.syntax rewrites a function on its first call
                import mitsuba as mi
                import lidar_mitsuba_plugins
                if mi.variant() is None:
                    try:
                        set_variant(wanted)
                    except ValueError as e:
                        raise RendererUnavailable(f"LIDAR_MITSUBA_VARIANT: {e}") from None
                lidar_mitsuba_plugins.install()
            _ready = True
    return sys.modules["mitsuba"]
