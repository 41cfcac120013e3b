"""What a Mitsuba scene's materials need from the tracer, read from the scene itself.

:func:`inspect` sorts every shape of a scene by its BSDF and media into the kinds the lidar
traces differently, and :class:`SceneMaterials` says what the scene needs: which integrator,
how many vertices per path, which group index delays the light, and what cannot be traced.

- **opaque** surfaces (any reflecting BSDF): ``pathlength``, one vertex at nadir.
- **interfaces** (a transmissive BSDF: ``dielectric``, ``roughdielectric``, ``water``): light
  crosses them, slowed by the interior's group index; a bottom under water needs three
  vertices (into the water, the bottom, out through the surface): ``mediapathlength``.
- **mirrors** (only delta lobes: a smooth ``dielectric`` or ``conductor``): a perfect
  mirror's nadir glint reaches a point receiver only from the footprint's exact specular
  point, :math:`F R^2 / (8 \\sigma^2 \\cdot 0.9)` times a snow plate's return (~10^8 at
  ATLAS's range): an idealisation that no Monte Carlo of a point receiver resolves; refused
  with a message naming the ``water`` BSDF (Cox-Munk slopes) for real water.
- **snow**: a homogeneous medium *under* a ``null`` surface, with no floor of its own: the
  subsurface walk (``volpathlength``) or its kernel.
- **air layers**: a homogeneous medium inside a closed ``null`` shape with a surface under it
  (fog, cloud, blowing snow, haze): attenuates, scatters and delays: ``mediapathlength``.
- **water bodies**: a medium inside a transmissive shape (absorbing, scattering water):
  ``mediapathlength``.

Which side of a surface a medium is on is decided by geometry: a vertical ray down through
the medium's shape that leaves the medium again and meets a surface below it finds a layer
in the air; one that stays in it finds snow.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import math

import numpy as np

from .variant import ensure_renderer

mi = ensure_renderer()        # the renderer, set up on first use
import drjit as dr  # noqa: E402  (after the libLLVM check)

from lidar_mitsuba_plugins.scene_utils import bsdf_group_index, scene_bounds

from ..constants import FWHM_PER_SIGMA, ParameterError
from ..ground.materials import Material, volume_words
from ..ground.snow import medium_events_cap
from ..instrument import Instrument
from ..track import spread_shots
from .scene import first_hits

#: vertices per path for a scene with interfaces (the bottom under water is the second; the
#: fourth sees the light the surface reflects back to the bottom, up to a third of the
#: bottom's return for a bright bottom: studies/lake.py) and for one with a layer in the air
#: whose scattered light reaches the ground in the field of view
INTERFACE_DEPTH = 4
AIR_DEPTH = 8
#: the largest share of a layer's forward-scattered light in the field of view that an
#: attenuation-only model may leave out (1 % of the ground's photons)
FORWARD_SHARE_MAX = 0.01

_LOBES = int(mi.BSDFFlags.Diffuse) | int(mi.BSDFFlags.Glossy)
_TRANSMIT = (int(mi.BSDFFlags.DeltaTransmission) | int(mi.BSDFFlags.GlossyTransmission)
             | int(mi.BSDFFlags.DiffuseTransmission))


@dataclass(frozen=True)
class Interface:
    """A transmissive surface: its shape, BSDF plugin, phase and group index, and whether it
    carries its own group index (the ``water`` BSDF) or uses its phase index."""
    shape: str
    plugin: str
    phase_index: float
    group_index: float
    own_group_index: bool

    def describe(self) -> str:
        how = ("its own group index" if self.own_group_index else
               "its phase index as group index (dispersion left out: <bsdf type=\"water\"> "
               "carries water's 532 nm group index)")
        return (f"'{self.shape}' ({self.plugin}, n = {self.phase_index:.4g}): light inside "
                f"travels at c / {self.group_index:.4g}, {how}")


@dataclass(frozen=True)
class Layer:
    """A homogeneous medium: the shape bounding it, its extinction [1/m], single-scattering
    albedo and vertical extent [m] (min z, max z of the bounding shape)."""
    shape: str
    sigma_t_per_m: float
    albedo: float
    z_m: tuple[float, float]
    g: float = 0.0
    floor_z_m: float | None = None

    @property
    def optical_depth(self) -> float:
        """Vertical optical depth through the layer."""
        return self.sigma_t_per_m * (self.z_m[1] - self.z_m[0])

    def forward_share(self, fov_radius_m: float) -> float:
        """The share of the ground's light scattered by the layer that still reaches the
        receiver from its field of view, to first order in the scattering optical depth:
        twice (the way down, and by reciprocity the way up) the layer's scattering optical
        depth times the Henyey-Greenstein probability of a deflection within
        atan(fov_radius / (layer base - ground)), the widest angle that can still land in the
        field of view from the layer's base,
        P(cos theta >= mu0) = (1 - g^2) / (2 g) (1 / (1 - g) - 1 / sqrt(1 + g^2 - 2 g mu0)).
        What an attenuation-only model (one vertex: Beer-Lambert both ways) leaves out.
        Against the full trace (tau 0.3, g 0.85, 200 m thick; tests/test_media.py): base
        1000 m: 0.52 % estimated, 0.53 +- 0.19 % traced; 300 m: 5.1 % and 3.3 %; 50 m: 40 %
        and 19 % (multiple scattering and the scattered light's own attenuation, left out
        here, lower it: an overestimate where it matters)."""
        if self.floor_z_m is None:
            return 1.0
        height = max(self.z_m[0] - self.floor_z_m, 1e-6)
        mu0 = math.cos(math.atan(fov_radius_m / height))
        g = self.g
        if abs(g) < 1e-6:
            p = 0.5 * (1.0 - mu0)
        else:
            p = (1 - g * g) / (2 * g) * (1 / (1 - g) - 1 / math.sqrt(1 + g * g - 2 * g * mu0))
        return 2.0 * self.albedo * self.optical_depth * p


@dataclass(frozen=True)
class SceneMaterials(Material):
    """What :func:`inspect` found in a scene, and what it needs from the tracer: a scene's own
    :class:`~lidar_mitsuba.ground.materials.Material` (``settings``: the scene's
    ``<integrator>`` parameters the run honours)."""
    opaque: tuple[str, ...] = ()
    interfaces: tuple[Interface, ...] = ()
    mirrors: tuple[str, ...] = ()
    snow_medium: mi.Medium | None = None
    air_layers: tuple[Layer, ...] = ()
    water_media: tuple[Layer, ...] = ()
    notes: tuple[str, ...] = field(default=())
    settings: dict = field(default_factory=dict)

    kind = "scene"            # (the shapes carry their own BSDFs: no mesh_bsdf)

    @property
    def needs_media_tracer(self) -> bool:
        """Light crosses interfaces or air layers: ``mediapathlength``."""
        return bool(self.interfaces or self.air_layers or self.water_media)

    @property
    def volume(self) -> bool:
        """Snow under a surface: one record per photon (``volpathlength``)."""
        return self.snow_medium is not None and not self.needs_media_tracer

    @property
    def gated(self) -> bool:
        """Layers in the air return light from every height: keep the range gate's."""
        return bool(self.air_layers)

    def depth(self, max_depth, *, fov_radius_m: float):
        """The scene's snow: its medium's interaction cap; water and air: :meth:`min_depth`;
        opaque surfaces: ``max_depth`` (``"auto"``: the bounce pilot's)."""
        if max_depth != "auto":
            return max_depth
        if self.volume:
            return medium_events_cap(self.snow_medium)
        return self.min_depth(fov_radius_m) if self.needs_media_tracer else max_depth

    def integrator(self, base: dict, *, max_depth: int) -> dict:
        """``mediapathlength`` for water and air, ``volpathlength`` for snow (with the scene's
        ``<integrator>`` group index, snow depth and base albedo), else ``pathlength``."""
        d = super().integrator(base, max_depth=max_depth)
        if self.needs_media_tracer:
            return {**d, "type": "mediapathlength",
                    **{k: v for k, v in self.settings.items() if k == "group_index"}}
        if self.volume:
            return {**d, "type": "volpathlength",
                    **{k: v for k, v in self.settings.items()
                       if k in ("group_index", "snow_depth_m", "base_albedo")}}
        return d

    def choices(self, *, max_depth: int, fov_radius_m: float, shots: int, timings_s: dict,
                facet_m: float | None = None):
        """Water and air: the scene's materials in words; snow: the walk's; an opaque
        scene: None (the bounces chose)."""
        if self.needs_media_tracer:
            return self.describe(max_depth=max_depth, fov_radius_m=fov_radius_m), []
        if self.volume:
            return volume_words(None, max_depth=max_depth, table=None, shots=shots,
                                timings_s=timings_s, facet_m=facet_m)
        return None

    def config(self) -> dict:
        return {"snow": None, "snow_model": "walk" if self.volume else None,
                "snow_kernel": None}

    def min_depth(self, fov_radius_m: float) -> int:
        """The fewest vertices per path that see what the scene holds: a layer in the air
        whose forward-scattered light stays out of the receiver's field of view
        (:meth:`Layer.forward_share` below :data:`FORWARD_SHARE_MAX`: a thin cloud high
        above) needs one (Beer-Lambert both ways: "model no more than a scene needs");
        other layers and media :data:`AIR_DEPTH`; interfaces :data:`INTERFACE_DEPTH`."""
        if self.water_media or any(lay.forward_share(fov_radius_m) > FORWARD_SHARE_MAX
                                   for lay in self.air_layers):
            return AIR_DEPTH
        return INTERFACE_DEPTH if self.interfaces else 1

    def describe(self, *, max_depth: int, fov_radius_m: float) -> list[str]:
        """The scene's materials and the model they choose, in words (``max_depth``: the
        run's vertices per path)."""
        if not self.needs_media_tracer:
            return []
        out = []
        if self.interfaces:
            out.append("interfaces: " + "; ".join(i.describe() for i in self.interfaces))
        for lay in self.air_layers:
            share = lay.forward_share(fov_radius_m)
            out.append(f"a layer in the air, '{lay.shape}' (z {lay.z_m[0]:g} .. "
                       f"{lay.z_m[1]:g} m, extinction {lay.sigma_t_per_m:.3g} /m, optical "
                       f"depth {lay.optical_depth:.3g}, single-scattering albedo "
                       f"{lay.albedo:.3g}, g {lay.g:.2f}): Beer-Lambert both ways; its "
                       f"forward-scattered light in the field of view is at most "
                       f"{100 * share:.2g} % of the ground's"
                       + (" (left out: one vertex)" if max_depth == 1 else ""))
        for lay in self.water_media:
            out.append(f"water '{lay.shape}' with a medium (extinction {lay.sigma_t_per_m:.3g}"
                       f" /m, albedo {lay.albedo:.3g})")
        if self.needs_media_tracer:
            out.append(f"traced by mediapathlength with {max_depth} vertices per path "
                       f"(the scene's materials need {self.min_depth(fov_radius_m)})")
        return out + list(self.notes)


def _medium_layer(shape, medium, name: str, floor_z_m: float | None = None) -> Layer:
    mei = dr.zeros(mi.MediumInteraction3f)
    sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei, True)
    st, ss = float(sigma_t[0][0]), float(sigma_s[0][0])
    b = shape.bbox()
    g = mi.traverse(medium.phase_function())
    return Layer(shape=name, sigma_t_per_m=st, albedo=ss / st if st > 0 else 0.0,
                 z_m=(float(b.min[2]), float(b.max[2])),
                 g=float(np.asarray(g["g"]).ravel()[0]) if "g" in g else 0.0,
                 floor_z_m=floor_z_m)


def _floor_z(scene: mi.Scene, shape) -> float | None:
    """The height [m] of the surface a vertical ray down through the middle of ``shape`` meets
    after leaving the medium inside it (a layer in the air), or ``None`` when the ray stays
    in the medium or meets nothing (snow, under its surface)."""
    b = shape.bbox()
    x, y = 0.5 * (b.min[0] + b.max[0]), 0.5 * (b.min[1] + b.max[1])
    top = float(scene_bounds(scene)[1][2]) + 1.0
    ray = mi.Ray3f(mi.Point3f(x, y, top), mi.Vector3f(0, 0, -1))
    inside = False
    for _ in range(16):
        si = scene.ray_intersect(ray)
        if not bool(si.is_valid()[0]):
            return None
        null = mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)
        if not bool(null[0]):          # a surface under the medium, after leaving it
            return None if inside else float(si.p.z[0])
        inside = not _is_null_ptr(si.target_medium(ray.d))
        ray = mi.Ray3f(si.p + ray.d * (1e-4 * (1.0 + abs(float(si.p.z[0])))), ray.d)
    return None


def _is_null_ptr(ptr) -> bool:
    return int(dr.reinterpret_array(mi.UInt32, ptr)[0]) == 0


def inspect(scene: mi.Scene) -> SceneMaterials:
    """Sort the shapes of ``scene`` by what their materials need (see the module's text).

    Raises:
        ValueError: a medium that is not homogeneous, or a scene with both snow and a layer
            in the air (one kind of medium per scene is supported).
    """
    opaque, interfaces, mirrors, air, water, snow = [], [], [], [], [], []
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        flags = int(bsdf.flags())
        null = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)
        name = shape.id() or shape.class_name()
        if flags & _TRANSMIT and not null:
            params = mi.traverse(bsdf)
            n = float(np.asarray(params["eta"]).ravel()[0]) if "eta" in params else 1.0
            n_g = bsdf_group_index(bsdf)
            own = "eta" not in params or n_g != n
            if not flags & _LOBES:
                mirrors.append(name)
            interfaces.append(Interface(shape=name, plugin=bsdf.class_name(), phase_index=n,
                                        group_index=n_g, own_group_index=own))
        elif not null:
            (opaque if flags & _LOBES else mirrors).append(name)
        for med in {id(m): m for m in (shape.interior_medium(), shape.exterior_medium())
                    if m is not None}.values():
            if not med.is_homogeneous():
                raise ValueError(f"shape '{name}': only homogeneous media are supported "
                                 f"(got {med.class_name()})")
            if not null:
                water.append(_medium_layer(shape, med, name))
            elif (floor := _floor_z(scene, shape)) is not None:
                air.append(_medium_layer(shape, med, name, floor))
            elif not any(med is m for m in snow):
                snow.append(med)
    if snow and (air or water):
        raise ValueError("the scene has snow (a medium under its surface) and a medium in the "
                         "air or in water: one kind of medium per scene is supported")
    if len(snow) > 1:
        raise ValueError(f"the scene has {len(snow)} media under its surfaces; one (the "
                         f"snow) is supported")
    return SceneMaterials(opaque=tuple(opaque), interfaces=tuple(interfaces),
                          mirrors=tuple(mirrors), snow_medium=snow[0] if snow else None,
                          air_layers=tuple(air), water_media=tuple(water))


def first_surfaces(scene: mi.Scene, x_m, y_m) -> list[str]:
    """The names of the shapes first met by vertical rays down at (x_m, y_m), through
    ``null`` surfaces (the boundaries of media), without repeats, in the order met."""
    names = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0]):
             shape.id() or shape.class_name() for shape in scene.shapes()}
    si, _ = first_hits(scene, x_m, y_m, through_null=True)
    hit = (si.is_valid() & ~mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)).numpy()
    ids = dr.reinterpret_array(mi.UInt32, si.shape).numpy()[hit]
    first = sorted(np.unique(ids, return_index=True)[1])     # the order met along the shots
    return list(dict.fromkeys(names[int(ids[i])] for i in first))


def mirror_message(shape: str, instrument) -> str:
    """Why a perfect mirror under the track is refused, with its glint's closed form at this
    instrument's geometry and the way to model real water (one line)."""
    sigma = instrument.footprint_sigma_m
    ratio = 0.0204 * instrument.altitude_m ** 2 / (8.0 * sigma ** 2 * 0.9)
    return (f"shape '{shape}' under the track has a smooth (delta) BSDF, a perfect mirror: its "
            f"nadir glint comes only from the footprint's specular point, F R^2 / (8 sigma^2 "
            f"0.9) = {ratio:.2g} times a Lambertian plate for water (F = 0.0204) at "
            f"{instrument.altitude_m:g} m, and from nowhere once the surface tilts by "
            f"{sigma / instrument.altitude_m * 1e6:.2g} microradians; real water is never that "
            f"flat: give it <bsdf type=\"water\"> with wind_speed_mps (Cox-Munk slopes) or a "
            f"small mss for a calm lead (lidar_mitsuba.ground.water.water_bsdf)")


def refuse_mirrors(mats: SceneMaterials, scene: mi.Scene, x_m, y_m, instrument) -> None:
    """Raise ``ValueError`` (:func:`mirror_message`) when a perfect mirror of ``mats`` lies
    under the footprint centres (x_m, y_m) [m] (64 of them, spread along the track)."""
    if not mats.mirrors:
        return
    pick = spread_shots(np.size(x_m), 64)
    hit = [m for m in first_surfaces(scene, np.asarray(x_m)[pick], np.asarray(y_m)[pick])
           if m in mats.mirrors]
    if hit:
        raise ValueError(mirror_message(hit[0], instrument))


# pathlength parameters a scene's <integrator> may set -> (Instrument field, factor to it)
XML_GEOMETRY = {"altitude_m": ("altitude_m", 1.0),
                 "footprint_sigma_m": ("footprint_diameter_m", 4.0),
                 "pulse_sigma_ns": ("pulse_fwhm_ns", FWHM_PER_SIGMA),
                 "fov_radius_m": ("fov_diameter_m", 2.0)}


def scene_settings(scene: mi.Scene, instrument: Instrument, max_depth):
    """Honour a ``<integrator type="pathlength">`` in the scene: the parameters it sets become
    the run's unless the instrument or ``max_depth`` set another value (refused: one place).
    Returns ``(instrument, max_depth, max_lanes, honoured)``."""
    explicit = getattr(scene.integrator(), "explicit", None)
    if not explicit:                 # no integrator, another one (for mi.render), or defaults
        return instrument, max_depth, None, {}
    nominal = Instrument(beam=instrument.beam)
    changes = {}
    for key, (name, factor) in XML_GEOMETRY.items():
        if key not in explicit:
            continue
        value, given = explicit[key] * factor, getattr(instrument, name)
        if given != getattr(nominal, name) and not math.isclose(given, value, rel_tol=1e-9):
            raise ParameterError(name, f"the scene's <integrator type=\"pathlength\"> sets "
                                 f"{key} = {explicit[key]:g}, i.e. {name} = {value:g}, and "
                                 f"{given:g} was given too: set it in one place")
        changes[name] = value
    if "max_depth" in explicit:
        if max_depth == "auto":
            max_depth = int(explicit["max_depth"])
        elif max_depth != explicit["max_depth"]:
            raise ParameterError("max_depth", f"the scene's <integrator type=\"pathlength\"> "
                                 f"sets max_depth = {explicit['max_depth']} and {max_depth} "
                                 f"was given too: set it in one place")
    if changes:
        instrument = instrument.replace(**changes)
    return instrument, max_depth, explicit.get("max_lanes"), dict(explicit)
