"""Third-party modules that other libraries import at their own import but a granule never
uses, loaded the first time one of their attributes is read instead (issue 43: what a cold
process pays before its first ray).

rasterio imports ``boto3`` when it is installed (``rasterio.session``: an ``AWSSession`` for
``s3://`` paths), and the test extra's ``h5coro`` installs it: ~0.25 s of a quiet 2-core
machine's start, ~1 s under load (``python -X importtime``), for the S3 sessions a local DEM
never opens. :func:`rasterio` hands ``rasterio.session`` a module that is imported for real
the first time it is used: ``boto3 is not None`` still holds, so an ``s3://`` DEM gets its
AWS session as before.
"""
from __future__ import annotations

import importlib.util
import sys
import threading
import types

#: what rasterio's import pulls in and a local DEM never uses
RASTERIO_DEFERRED = ("boto3",)


class Deferred(types.ModuleType):
    """A stand-in for module ``spec.name`` that imports it for real on the first read of an
    attribute it lacks (and hands that attribute on): an ``import`` of the name finds it in
    ``sys.modules`` and runs nothing (its ``__spec__`` says it is not initializing; Python
    3.11's :class:`importlib.util.LazyLoader` loads on that very look-up), ``x is not None``
    holds, ``x.f(...)`` is the real module's ``f``. The real module then replaces it in
    ``sys.modules``."""

    def __init__(self, spec):
        super().__init__(spec.name)
        self.__spec__ = spec
        self.__dict__["_lock"] = threading.Lock()
        self.__dict__["_real"] = None

    def _load(self) -> types.ModuleType:
        with self._lock:
            if self._real is None:
                if sys.modules.get(self.__name__) is self:
                    del sys.modules[self.__name__]
                self.__dict__["_real"] = importlib.import_module(self.__name__)
            return self._real

    def __getattr__(self, attr: str):
        if attr in ("_lock", "_real", "_load"):
            raise AttributeError(attr)
        return getattr(self._load(), attr)


def defer(name: str) -> types.ModuleType | None:
    """Put a :class:`Deferred` stand-in for module ``name`` into ``sys.modules``; nothing
    when ``name`` is imported already or not installed. Returns what ``sys.modules`` then
    holds under ``name`` (None: not installed)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None:
        return None
    sys.modules[name] = module = Deferred(spec)
    return module


def rasterio() -> types.ModuleType:
    """``rasterio``, imported with :data:`RASTERIO_DEFERRED` deferred."""
    if "rasterio" not in sys.modules:
        for name in RASTERIO_DEFERRED:
            defer(name)
    import rasterio as module
    return module
