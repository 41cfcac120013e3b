"""Vegetation in scenes: forest stands and their representations (issue 42).

- :mod:`.stand`: a seeded forest generator over any surface or DEM (:func:`~.stand.stand`),
  the :class:`~.stand.Stand` it returns (trees as numpy arrays: the description every
  representation shares). Pure numpy.
- :mod:`.leaf_angles`: the leaf angle distributions, Ross's G-function and Nilson's gap
  probability. Pure numpy.
- :mod:`.optics`: leaf, needle, bark, litter, soil and snow reflectance and transmittance at
  532 nm, each with its source.
- :mod:`.explicit`: the explicit representation: leaves and needle shoots as facets inside
  the crowns, stems as bark frustums, copies of a few prototype trees merged into one mesh
  per tile, with the bi-Lambertian leaf BSDF (``plugins/bilambertian.py``).
- :mod:`.forest`: :class:`~.forest.ForestSurface`, a stand over any ground
  :class:`~lidar_mitsuba.ground.surface.Surface`, and :func:`~.forest.forest`, the front door
  (``lm.forest``). Its ``representation`` picks how the stand is traced
  (:data:`~.forest.REPRESENTATIONS`, the one place a representation plugs in).
"""
