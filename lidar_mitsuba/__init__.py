"""lidar_mitsuba: first-principles simulation of spaceborne photon-counting lidar.

``import lidar_mitsuba`` finds a usable libLLVM for Dr.Jit (or stops with a message saying what
to install), selects the Mitsuba variant named by the environment variable
``LIDAR_MITSUBA_VARIANT`` (default ``llvm_ad_mono``) unless one is already active, and
registers the plugins ``ward`` (BSDF), ``pathlength`` and ``volpathlength`` (integrators) in
every variant. With ``LIDAR_MITSUBA_VARIANT=cuda_ad_mono`` a machine needs no libLLVM.
"""
import os as _os

__version__ = "0.1.0"

from ._llvm import ensure_libllvm as _ensure_libllvm

_ensure_libllvm(required=not _os.environ.get("LIDAR_MITSUBA_VARIANT", "").startswith("cuda"))

from . import variant as _variant  # noqa: E402

_variant.init()

from .variant import set_variant, DEFAULT_VARIANT  # noqa: E402,F401

