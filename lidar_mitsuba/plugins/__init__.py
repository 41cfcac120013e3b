"""Mitsuba plugins of lidar_mitsuba, one per file, each registering itself.

- ``ward.py``: ``<bsdf type="ward">``, the Ward BRDF.
- ``pathlength.py``: ``<integrator type="pathlength">``, the lidar path-length integrator.
- ``volpathlength.py``: ``<integrator type="volpathlength">``, the same with a participating
  medium (snow as a volume); it subclasses ``pathlength`` and is loaded after it.

They are executed once per Mitsuba variant by :mod:`lidar_mitsuba.variant` (``import
lidar_mitsuba`` is enough); do not import these files directly.
"""
