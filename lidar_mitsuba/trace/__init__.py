"""The renderer stage: the Mitsuba variant and libLLVM set-up
(:func:`~lidar_mitsuba.trace.variant.ensure_renderer`), scenes, the materials a scene holds and
what they need from the tracer, the bounce pilot, the path budget and the trace -> detect
stream. With the plugins, the only place that imports Mitsuba or Dr.Jit at import time (its
``stream`` and ``path_budget`` do not); this ``__init__`` imports nothing."""
