"""The renderer's modules for code that uses them throughout but must import without them
(the studies): ``mi`` and ``dr`` stand for ``mitsuba`` and ``drjit``, and :func:`module` for a
trace module, each loaded (and the renderer set up, :func:`~.variant.ensure_renderer`) the
first time one of its attributes is used.

>>> from lidar_mitsuba.trace.lazy import mi      # nothing loaded yet
>>> mi.variant()                                 # doctest: +SKIP
'llvm_ad_mono'
"""
from __future__ import annotations

import importlib
import types

from .variant import ensure_renderer


class LazyModule:
    """A module loaded on first attribute access, after the renderer is set up."""

    def __init__(self, name: str):
        self._name = name
        self._module: types.ModuleType | None = None

    def __getattr__(self, attr: str):
        if self._module is None:
            ensure_renderer()
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attr)

    def __repr__(self) -> str:
        return f"<lazy module {self._name!r}{'' if self._module is None else ' (loaded)'}>"


def module(name: str) -> LazyModule:
    """``name`` (e.g. ``"lidar_mitsuba.trace.scene"``), loaded when first used."""
    return LazyModule(name)


mi = LazyModule("mitsuba")
dr = LazyModule("drjit")
