"""Standalone Mitsuba 3 plugins for photon-counting lidar (``lidar_mitsuba_plugins``).

They depend on Mitsuba and Dr.Jit only; the lidar pipeline (``lidar_mitsuba``) builds on
them, never the other way round.

- ``ward.py``: ``<bsdf type="ward">``, the Ward BRDF (three normalisations, importance
  sampled, textures as albedo).
- ``water.py``: ``<bsdf type="water">``, a wind-roughened water surface (Beckmann dielectric,
  Cox-Munk slopes from the wind speed, Quan-Fry refractive and group indices).
- ``bilambertian.py``: ``<bsdf type="bilambertian">``, a thin leaf: Lambertian reflection
  (R) back to the lit side and Lambertian transmission (T) to the other, two-sided.
- ``pathlength.py``: ``<integrator type="pathlength">``, the lidar path-length integrator:
  per photon return, its shot, exact round-trip time and radiometric weight.
- ``volpathlength.py``: ``<integrator type="volpathlength">``, the same with a participating
  medium (snow as a volume): a random walk under each facet; it subclasses ``pathlength``.
- ``snowkernel.py``: ``<integrator type="snowkernel">``, the same snow as a tabulated kernel
  (the walk's return weight and delay against incidence angle, ``kernel_table.py``): the
  cost of a surface hit; it subclasses ``pathlength``.
- ``mediapathlength.py``: ``<integrator type="mediapathlength">``, the same through water
  (transmissive BSDFs, the group index delaying the light inside) and through participating
  media in the air (fog, cloud), with next-event returns by transmittance; it subclasses
  ``pathlength``.
- ``canopy.py``: ``<integrator type="canopy">``, tree crowns as a turbid medium of leaves
  (Ross's G, bi-Lambertian leaves, the monostatic hot spot) over the scene's ground, traced
  by Monte Carlo (``mode="turbid"``) or as a gap-probability layer (``mode="gap"``); the
  crowns come from a table (``canopy_table.py``), their kernel code from
  ``canopy_crowns.py``; it subclasses ``pathlength``.

Use from plain Mitsuba::

    import mitsuba as mi
    mi.set_variant("llvm_ad_mono")
    import lidar_mitsuba_plugins          # registers ward, water and the integrators
                                          # (lidar_mitsuba_plugins.install() if it was
                                          # imported before Mitsuba)
    scene = mi.load_file("scene.xml")      # <bsdf type="ward"/>, <integrator type="pathlength"/>
    image = mi.render(scene)               # a lidar-intensity image
    returns = scene.integrator().trace(scene, shot_x_m=..., shot_y_m=...)

Python plugins subclass variant-specific classes (``mi.BSDF`` differs between
``llvm_ad_mono`` and ``cuda_ad_mono``), so each plugin file is executed once per variant,
under its own module name (``lidar_mitsuba_plugins._<variant>_<name>``), and registers
itself with ``mi.register_*`` there. :func:`install` registers them in the active variant
and, through a Mitsuba variant callback, in every variant activated later; importing this
package calls it when Mitsuba is already imported (as above), and ``lidar_mitsuba`` calls it
when it sets its renderer up. Scalar variants are skipped: the plugins are vectorised. The
shared modules below import without Mitsuba, so a pipeline that only reads its files never
loads it.

Shared, variant-independent modules: ``constants`` (c, the FWHM factor, the reference plate,
the nominal geometry), ``returns`` (the integrators' output record), ``scene_utils`` (scene
bounds and medium), ``kernel_table`` (the layout of a snow kernel's table), ``canopy_table``
(a stand's crowns and foliage, and the grids that find them), ``water_optics``
(Cox & Munk's slopes and Quan & Fry's index, the ``water`` BSDF's closed forms); and
``canopy_crowns`` (the ``canopy`` plugin's crown kernels: it needs Mitsuba, not a variant).
"""
from __future__ import annotations

import gc
import importlib.util
import pathlib
import sys
import types

PLUGIN_FILES = ("ward", "water", "bilambertian", "pathlength", "volpathlength", "snowkernel",
                "mediapathlength", "canopy")
"""The plugin files, in load order (``volpathlength``, ``snowkernel`` and
``mediapathlength`` build on ``pathlength``)."""

_registered: set[str] = set()


def register(variant: str | None = None) -> None:
    """Execute every plugin file once in ``variant`` (default: the active one), so that
    ``ward``, ``pathlength`` and ``volpathlength`` can be loaded there. Idempotent; a scalar
    variant or no variant is skipped."""
    import mitsuba as mi
    variant = variant if variant is not None else mi.variant()
    if variant is None or variant.startswith("scalar") or variant in _registered:
        return
    if mi.variant() != variant:
        raise ValueError(f"register({variant!r}): activate the variant first "
                         f"(mi.set_variant), the plugins subclass its classes")
    here = pathlib.Path(__file__).parent
    for name in PLUGIN_FILES:
        spec = importlib.util.spec_from_file_location(f"{__name__}._{variant}_{name}",
                                                      here / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module   # a later plugin may build on it (volpathlength)
        spec.loader.exec_module(module)   # registers itself with mi.register_*
    _registered.add(variant)


def module(name: str, variant: str | None = None) -> types.ModuleType:
    """The plugin file ``name`` (``"pathlength"``, ...) as executed in ``variant`` (default:
    the active one), e.g. to reach its helpers or classes. Registers the plugins first."""
    import mitsuba as mi
    variant = variant if variant is not None else mi.variant()
    register(variant)
    return sys.modules[f"{__name__}._{variant}_{name}"]


def _on_variant_change(old: str | None, new: str | None) -> None:
    # Free what the previous variant left unreachable (Python plugin objects sit in reference
    # cycles): Dr.Jit's virtual-call registry is shared by the variants of one backend, and a
    # dead object of another variant still registered there can break the compilation of
    # this variant's kernels ("invalid redefinition of function").
    gc.collect()
    register(new)


_installed = False


def install() -> None:
    """Register the plugins in the active variant and, through a Mitsuba variant callback, in
    every variant activated later. Idempotent. Runs on ``import lidar_mitsuba_plugins`` when
    Mitsuba is already imported (the plain-Mitsuba recipe above); ``lidar_mitsuba`` calls it
    when it sets the renderer up. The shared modules (``constants``, ``returns``,
    ``kernel_table``) import without Mitsuba."""
    global _installed
    import mitsuba as mi
    if not _installed:
        mi.detail.add_variant_callback(_on_variant_change)
        _installed = True
    register()


if "mitsuba" in sys.modules:
    install()
