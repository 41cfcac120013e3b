"""Mitsuba variant selection and registration of our plugins in every variant.

Python plugins subclass variant-specific classes (``mi.BSDF`` differs between ``llvm_ad_mono``
and ``cuda_ad_mono``), so each plugin file is executed once per variant, under its own module
name, whenever that variant becomes active.
"""
from __future__ import annotations

import gc
import importlib.util
import os
import pathlib
import sys

import drjit as dr
import mitsuba as mi

DEFAULT_VARIANT = "llvm_ad_mono"
SUPPORTED_VARIANTS = ("llvm_ad_mono", "cuda_ad_mono", "llvm_ad_rgb", "cuda_ad_rgb")
PLUGIN_FILES = ("ward", "pathlength", "volpathlength")

_registered: set[str] = set()


def _register_plugins(variant: str | None) -> None:
    if variant is None or variant.startswith("scalar") or variant in _registered:
        return
    plugin_dir = pathlib.Path(__file__).parent / "plugins"
    for name in PLUGIN_FILES:
        path = plugin_dir / f"{name}.py"
        spec = importlib.util.spec_from_file_location(
            f"lidar_mitsuba.plugins._{variant}_{name}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module   # a later plugin may build on it (volpathlength)
        spec.loader.exec_module(module)  # registers itself with mi.register_*
    _registered.add(variant)


def _on_variant_change(old: str | None, new: str | None) -> None:
    # Free what the previous variant left unreachable (Python plugin objects sit in reference
    # cycles): Dr.Jit's virtual-call registry is shared by the variants of one backend, and a
    # dead object of another variant still registered there can break the compilation of
    # this variant's kernels ("invalid redefinition of function").
    gc.collect()
    _register_plugins(new)


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
    _register_plugins(name)
    return name


def init() -> None:
    """Called on ``import lidar_mitsuba``: keep plugins registered in whatever variant is active."""
    mi.detail.add_variant_callback(_on_variant_change)
    if mi.variant() is None:
        wanted = os.environ.get("LIDAR_MITSUBA_VARIANT") or DEFAULT_VARIANT
        try:
            set_variant(wanted)
        except ValueError as e:
            raise ImportError(f"LIDAR_MITSUBA_VARIANT: {e}") from None
    _register_plugins(mi.variant())
