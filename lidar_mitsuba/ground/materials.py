"""Materials as types: what a surface is made of, and what that needs from the tracer.

Every run has one :class:`Material`; :func:`lidar_mitsuba.planning.plan` asks it, and nothing
else, which integrator traces it, how many vertices a path needs, how many records a path
leaves, and what goes on the built-in surface's mesh. The kinds:

- :class:`Reflector`: a Ward or any other Mitsuba BSDF on the surface (``pathlength``; the
  bounces are the pilot's choice, one at nadir on a single-bounce surface).
- :class:`Snow`: a snow volume under the surface (:class:`~lidar_mitsuba.ground.snow.SnowVolume`),
  walked (``volpathlength``) or as its tabulated kernel (``snowkernel``); one record per photon
  whatever its interactions, delayed by the snow's group index.
- a scene's own (:class:`lidar_mitsuba.trace.materials.SceneMaterials`, read from a Mitsuba
  scene): opaque BSDFs, water and other interfaces (a dielectric with its group index), media
  in the air and in water, snow under a ``null`` surface.

Adding a material is adding a class with these methods (:class:`Material` lists them).

>>> import lidar_mitsuba as lm
>>> from lidar_mitsuba.ground.materials import Reflector
>>> m = Reflector(lm.ground.brdf.ward_bsdf_dict(rho_d=0.9))           # doctest: +SKIP
>>> m.integrator({"type": "pathlength", "max_depth": 1}, max_depth=2)   # doctest: +SKIP
{'type': 'pathlength', 'max_depth': 2}
"""
from __future__ import annotations

from dataclasses import dataclass

from .snow import SnowVolume
from .snow import kernel as snow_kernel


class Material:
    """The questions the planner asks a material (the base class answers for an opaque
    reflector; a kind overrides what differs).

    Attributes:
        kind: a short name (``"reflector"``, ``"snow"``, ``"scene"``).
        volume: paths leave one record per photon, whatever their vertices (a volume's walk):
            the corridor is the footprints', the scout counts one return per path.
        gated: returns outside the range gate are dropped at the tracer (layers in the air
            return light from every height).
        snow: the :class:`~lidar_mitsuba.ground.snow.SnowVolume` traced, or None.
        mesh_bsdf: what a built-in surface's mesh carries (a BSDF dict or a snow volume;
            None for a Mitsuba scene, whose shapes carry their own).
    """
    kind = "reflector"
    volume = False
    gated = False
    snow: SnowVolume | None = None
    mesh_bsdf: object = None

    def depth(self, max_depth, *, fov_radius_m: float):
        """The vertices per path this material needs given the run's ``max_depth`` (an int,
        or ``"auto"``: left to the bounce pilot)."""
        return max_depth

    def integrator(self, base: dict, *, max_depth: int) -> dict:
        """The Mitsuba integrator dict, from the instrument's ``pathlength`` dict ``base``."""
        return {**base, "max_depth": int(max_depth)}

    def returns_per_path(self, max_depth: int) -> int:
        """Records a traced path can leave (the scout's unit)."""
        return 1 if self.volume else int(max_depth)

    def describe(self, *, max_depth: int, fov_radius_m: float) -> list[str]:
        """The material and its model in words (``--explain``), one line each."""
        return []

    def choices(self, *, max_depth: int, fov_radius_m: float, shots: int, timings_s: dict,
                facet_m: float | None = None) -> tuple[list[str], list[str]] | None:
        """What the material chose, in words, and its warnings, once the run is done (None:
        the bounces chose the model, and the pilot says so)."""
        return None

    def prepared(self, *, progress: bool = False) -> tuple[Material, float]:
        """This material with what it needs computed before tracing (a snow kernel's table),
        and the seconds that took."""
        return self, 0.0

    def config(self) -> dict:
        """The material's entries in a result's ``config``."""
        return {"snow": None, "snow_model": None, "snow_kernel": None}


@dataclass(frozen=True)
class Reflector(Material):
    """A surface BSDF: Ward (the paper's) or any Mitsuba BSDF dict.

    Attributes:
        bsdf: the Mitsuba BSDF dict on the surface's mesh.
        given: the user gave it (``bsdf=``), rather than the surface's default.
    """
    bsdf: dict
    given: bool = False

    @property
    def mesh_bsdf(self):
        return self.bsdf


@dataclass(frozen=True)
class Snow(Material):
    """A snow volume under the surface.

    Attributes:
        snow: the snowpack (optics, depth, base, crust).
        model: ``"walk"`` (``volpathlength``: every scattering traced) or ``"kernel"``
            (``snowkernel``: the walk tabulated against incidence, at the cost of a surface
            hit).
        table_path, table: the kernel's table file and summary, once :meth:`prepared`.
    """
    snow: SnowVolume
    model: str = "kernel"
    table_path: str | None = None
    table: dict | None = None

    kind = "snow"
    volume = True

    @property
    def mesh_bsdf(self):
        return self.snow

    def depth(self, max_depth, *, fov_radius_m: float):
        return self.snow.events_cap

    def integrator(self, base: dict, *, max_depth: int) -> dict:
        if self.model == "kernel":
            return {**base, "max_depth": 1, "type": "snowkernel",
                    "filename": str(self.table_path)}
        return {**base, **self.snow.integrator_params(), "max_depth": int(max_depth)}

    def describe(self, *, max_depth: int, fov_radius_m: float) -> list[str]:
        return [f"snow: {self.snow.describe()} ({self.model})"]

    def choices(self, *, max_depth: int, fov_radius_m: float, shots: int, timings_s: dict,
                facet_m: float | None = None) -> tuple[list[str], list[str]]:
        return volume_words(self.snow, max_depth=max_depth, table=self.table, shots=shots,
                            timings_s=timings_s, facet_m=facet_m)

    def prepared(self, *, progress: bool = False) -> tuple[Material, float]:
        if self.model != "kernel" or self.table_path is not None:
            return self, 0.0
        import time
        t0 = time.perf_counter()
        path, table = snow_kernel.table(self.snow, progress=progress)
        return (Snow(self.snow, self.model, table_path=str(path), table=table),
                time.perf_counter() - t0)

    def config(self) -> dict:
        return {"snow": self.snow.config(), "snow_model": self.model,
                "snow_kernel": None if self.table is None else snow_kernel.summary(self.table)}


def volume_words(snow: SnowVolume | None, *, max_depth: int, table: dict | None, shots: int,
                 timings_s: dict, facet_m: float | None) -> tuple[list[str], list[str]]:
    """A snow volume's lines for ``--explain`` (``snow``: None for a scene's ``<medium>``;
    ``table``: the kernel's, when it is the model) and the kernel's warning on coarse facets."""
    out, warns = [], []
    out.append(snow.describe() if snow is not None else
               f"snow volume on (the scene's <medium>), up to {max_depth} interactions "
               f"per photon")
    if table is not None:
        out.append(_kernel_words(table))
        w = snow_kernel.plane_warning(table, facet_m=facet_m)
        if w is not None:
            warns.append(w)
    if "total_s" in timings_s:
        total = timings_s["total_s"]
        rate = shots / max(total, 1e-9)
        out.append(f"its cost: {rate:.3g} shots/s end to end ({total:.3g} s for {shots} shots"
                   + (f", of which {timings_s.get('kernel_table_s', 0.0):.3g} s getting the table)"
                      if table is not None else
                      "), some hundred times slower than the surface alone (`lidar-mitsuba"
                      " bench` measures the ratio); --snow-model kernel (the default for "
                      "--snow-grain-um) runs at the cost of a surface hit; "
                      + ("--snow-similarity-g 0 traces ~9x fewer scatterings, with h_li "
                         "within ~1 cm in bench's check"
                         if snow is None or snow.similar_to_g is None else
                         "similarity-rescaled: h_li within ~1 cm of the exact phase "
                         "function in bench's check")))
    return out, warns


def _kernel_words(t: dict) -> str:
    """The snow kernel's line for ``--explain``."""
    s = snow_kernel.summary(t)
    return (f"snow model: kernel (--snow-model kernel; the full walk tabulated against incidence "
            f"angle, {s['nodes']} angles, {s['photons_nadir']} walk photons at nadir, cached on "
            f"disk): at nadir a return weight of {s['weight_nadir']:.3f} per photon and a mean "
            f"extra path of {100 * s['mean_extra_path_nadir_m']:.1f} +- "
            f"{100 * s['mean_extra_path_se_nadir_m']:.1f} cm (the table's own Monte Carlo "
            f"error); each photon's delay is drawn from it at the cost of a surface hit, from "
            f"where it entered (the light comes out {100 * s['lateral_rms_max_m']:.2g} cm "
            f"from there, rms; {100 * s['lateral_p99_max_m']:.2g} cm, 99th percentile); "
            f"--snow-model walk traces the walk itself")
