"""lidar_mitsuba: first-principles simulation of spaceborne photon-counting lidar
(ICESat-2 / ATLAS-like) on Mitsuba 3 and Dr.Jit.

The front door: everything a run needs, under one name.

>>> import lidar_mitsuba as lm
>>> res = lm.simulate(instrument=lm.Instrument.atlas("weak"),
...                   surface=lm.SurfaceSpec(kind="fractal", p=1.8), shots=1000, seed=1)
...                                                                   # doctest: +SKIP
>>> res.report().overall                                              # doctest: +SKIP

The package folders follow the data flow: ``ground/`` (terrain, DEMs, surfaces, snow, water),
``vegetation/`` (forest stands over any ground, leaf optics, their representations),
``trace/`` (the renderer: variant, scenes, materials, the chunk stream), ``detector/`` (PMT,
dead time, records), ``products/`` (ATL03, ATL06, ATL07, classification, retrieval,
first-photon-bias correction), ``planning.py`` (a run's plan: ``lm.plan``), ``run.py`` (one
beam's run: ``lm.simulate`` = ``lm.plan`` + ``lm.stream`` + ``lm.assemble``), ``granule.py``
(six beams over a DEM), ``cli/``, ``studies/`` and ``sweep/``.

Importing the package loads neither Mitsuba nor Dr.Jit: the names below are looked up when
first used, and the renderer (a usable libLLVM, the variant ``LIDAR_MITSUBA_VARIANT``,
default ``llvm_ad_mono``, and the plugins) is set up the first time something traces
(:func:`ensure_renderer`). Reading our products and the pure stages never need it.
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name -> (module, attribute); nothing is imported until the name is used
_EXPORTS = {
    # a run
    "simulate": ("lidar_mitsuba.run", "simulate"),
    "plan": ("lidar_mitsuba.planning", "plan"),
    "RunPlan": ("lidar_mitsuba.planning", "RunPlan"),
    "stream": ("lidar_mitsuba.run", "stream"),
    "assemble": ("lidar_mitsuba.run", "assemble"),
    "SimulationResult": ("lidar_mitsuba.run", "SimulationResult"),
    "simulate_granule": ("lidar_mitsuba.granule", "simulate_granule"),
    "stream_granule": ("lidar_mitsuba.granule", "stream_granule"),
    "Instrument": ("lidar_mitsuba.instrument", "Instrument"),
    "Track": ("lidar_mitsuba.track", "Track"),
    "GeoTrack": ("lidar_mitsuba.geotrack", "GeoTrack"),
    "Site": ("lidar_mitsuba.geotrack", "Site"),
    # the ground: surfaces and materials
    "SurfaceSpec": ("lidar_mitsuba.ground.surface", "SurfaceSpec"),
    "Plane": ("lidar_mitsuba.ground.surface", "Plane"),
    "SceneSurface": ("lidar_mitsuba.ground.surface", "SceneSurface"),
    "Heightfield": ("lidar_mitsuba.ground.terrain", "Heightfield"),
    "fractal": ("lidar_mitsuba.ground.terrain", "fractal"),
    "DEM": ("lidar_mitsuba.ground.dem", "DEM"),
    "DEMSurface": ("lidar_mitsuba.ground.dem", "DEMSurface"),
    "SnowVolume": ("lidar_mitsuba.ground.snow", "SnowVolume"),
    "snow_from_grains": ("lidar_mitsuba.ground.snow", "snow_from_grains"),
    "water_bsdf": ("lidar_mitsuba.ground.water", "water_bsdf"),
    # vegetation: forest stands and their representations
    "forest": ("lidar_mitsuba.vegetation.forest", "forest"),
    "ForestSurface": ("lidar_mitsuba.vegetation.forest", "ForestSurface"),
    "stand": ("lidar_mitsuba.vegetation.stand", "stand"),
    "Stand": ("lidar_mitsuba.vegetation.stand", "Stand"),
    # the renderer
    "load_scene": ("lidar_mitsuba.trace.scene", "load_scene"),
    "inspect_materials": ("lidar_mitsuba.trace.materials", "inspect"),
    "ensure_renderer": ("lidar_mitsuba.trace.variant", "ensure_renderer"),
    "set_variant": ("lidar_mitsuba.trace.variant", "set_variant"),
    "DEFAULT_VARIANT": ("lidar_mitsuba.trace.variant", "DEFAULT_VARIANT"),
    # products
    "read_atl03": ("lidar_mitsuba.products.atl03", "read"),
    "write_atl03": ("lidar_mitsuba.products.atl03", "write"),
    # errors
    "ParameterError": ("lidar_mitsuba.constants", "ParameterError"),
    "SimulationWarning": ("lidar_mitsuba.constants", "SimulationWarning"),
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'lidar_mitsuba' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value          # looked up once
    return value


def __dir__():
    return __all__
