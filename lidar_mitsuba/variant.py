"""Mitsuba variant selection for the pipeline. The plugins (``lidar_mitsuba_plugins``, the
top-level ``plugins/`` folder) register themselves in every variant that becomes active.
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi

import lidar_mitsuba_plugins

DEFAULT_VARIANT = "llvm_ad_mono"
SUPPORTED_VARIANTS = ("llvm_ad_mono", "cuda_ad_mono", "llvm_ad_rgb", "cuda_ad_rgb")


def usable_variants() -> list[str]:
    """The supported variants this machine can run: CUDA ones only where a GPU is found, LLVM
    ones only where a usable libLLVM was (``import lidar_mitsuba`` under a CUDA variant points
    Dr.Jit at ``os.devnull`` when it finds none)."""
    return [v for v in SUPPORTED_VARIANTS if v in mi.variants() and _has_backend(v)]


def _has_backend(name: str) -> bool:
    """Whether the backend of JIT variant ``name`` can run here."""
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


def init() -> None:
    """Called on ``import lidar_mitsuba``: activate ``LIDAR_MITSUBA_VARIANT`` (default
    ``llvm_ad_mono``) unless a variant is active; the plugins follow every variant (their
    package's own variant callback)."""
    if mi.variant() is None:
        wanted = os.environ.get("LIDAR_MITSUBA_VARIANT") or DEFAULT_VARIANT
        try:
            set_variant(wanted)
        except ValueError as e:
            raise ImportError(f"LIDAR_MITSUBA_VARIANT: {e}") from None
    lidar_mitsuba_plugins.register()
