"""Lidar path-length integrator through dielectric interfaces and participating media
(``<integrator type="mediapathlength">``).

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``),
after ``pathlength``, on which it builds.
"""
from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi
import numpy as np

from lidar_mitsuba_plugins.constants import C_M_PER_NS, REFERENCE_ALBEDO
from lidar_mitsuba_plugins.scene_utils import group_index_table

_pathlength = sys.modules[f"lidar_mitsuba_plugins._{mi.variant()}_pathlength"]
_TRANSMISSION = (mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.GlossyTransmission
                 | mi.BSDFFlags.DiffuseTransmission)


class MediaPathLengthIntegrator(_pathlength.PathLengthIntegrator):
    r"""
    Lidar path-length integrator through water and air (:monosp:`mediapathlength`)
    -------------------------------------------------------------------------------

    The ``pathlength`` integrator for scenes whose light crosses interfaces and media: water
    (a ``dielectric``, ``roughdielectric`` or ``water`` BSDF, optionally with an absorbing
    and scattering ``<medium>`` inside it) and layers in the air (fog, cloud, blowing snow,
    haze: a homogeneous ``<medium>`` inside a ``null``-bounded shape above the ground).

    .. pluginparameters::

     * - max_depth
       - |int|
       - Vertices per photon path: surface interactions and volume scatterings (default 8).
         Crossing a ``null`` boundary is not a vertex. A lake bottom needs 3 (into the
         water, the bottom, out through the surface).
     * - group_index
       - |float|
       - Group index given to the interior of every transmissive BSDF that does not carry
         its own (default 0: each dielectric's phase index ``int_ior / ext_ior``; the
         ``water`` BSDF carries water's group index at 532 nm).
     * - (others)
       - as ``pathlength``: ``altitude_m``, ``footprint_sigma_m``, ``pulse_sigma_ns``,
         ``fov_radius_m``, ``max_lanes``.

    Per photon, a vertical ray from just above the scene (as ``pathlength``). In a medium,
    a free path is sampled (``Medium.sample_interaction``) up to the next surface; a
    scattering is a vertex, with the single-scattering albedo as throughput and the phase
    function sampled for the next direction. A ``null`` surface is crossed (the medium
    changes to its ``target_medium``); any other surface is a vertex, its BSDF sampled for
    the next direction (reflection or refraction).

    At every vertex, a next-event return toward the receiver: the phase function, or
    :math:`\pi f_r \cos\theta_o`, times the transmittance of the media crossed on the way up
    (a shadow ray through ``null`` surfaces, Beer-Lambert per homogeneous segment; any other
    surface occludes), over 0.9, so that a flat Lambertian 0.9 plate in clear air weighs 1.
    Light under a rough water surface returns at the surface's underside vertex, through
    the BSDF's transmission lobe; a smooth (delta) interface cannot be connected to a point
    receiver (simulate() refuses it at nadir with a message).

    Time of flight: the float64 legs between the spacecraft and the first and last vertex
    (as ``pathlength``), and every segment in between times the group index of the region
    it crosses: 1 in air and in air's media (their delay is ATL03's atmospheric
    correction), the group index inside a transmissive BSDF's interior (entered on a
    refraction against the surface normal, left on one along it).

    One slot per vertex and photon: ``depth`` is the vertex count (1 = first vertex).

    .. tabs::

        .. code-tab:: xml

            <integrator type="mediapathlength">
                <integer name="max_depth" value="8"/>
            </integrator>

        .. code-tab:: python

            {'type': 'mediapathlength', 'max_depth': 8}
    """

    #: parameters beyond ``pathlength``'s
    MEDIA_PARAMETERS = ("group_index",)
    #: null-surface crossings followed by a shadow ray toward the receiver
    SHADOW_CROSSINGS = 8

    def __init__(self, props: mi.Properties):
        if "max_depth" not in props:
            props["max_depth"] = 8
        super().__init__(props)
        self.group_index = float(props.get("group_index", 0.0))
        if not (self.group_index == 0.0 or 1.0 <= self.group_index <= 3.0):
            raise ValueError(f"mediapathlength: group_index out of range "
                             f"(got {self.group_index!r})")
        self.explicit.update({k: getattr(self, k) for k in self.MEDIA_PARAMETERS if k in props})
        self._ng = None

    def _core(self, scene: mi.Scene):
        table = group_index_table(scene, default=self.group_index or None)
        self._ng = mi.Float(np.asarray(table, np.float32))
        return self._media, self.max_depth

    # ------------------------------------------------------------- helpers (traced)
    @staticmethod
    def _sigma_t(medium, p: mi.Point3f, active: mi.Bool) -> mi.Float:
        """Extinction [1/m] of ``medium`` (a MediumPtr; 0 where null) at ``p``."""
        mei = dr.zeros(mi.MediumInteraction3f)
        mei.p = p
        return dr.select(active, medium.get_scattering_coefficients(mei, active)[2][0], 0.0)

    @dr.syntax
    def _transmittance(self, scene: mi.Scene, p: mi.Point3f, n: mi.Vector3f, wo: mi.Vector3f,
                       medium, active: mi.Bool) -> mi.Float:
        """Transmittance from ``p`` (on a surface of normal ``n``, or in a medium where
        ``n`` is 0) toward the receiver along ``wo``: Beer-Lambert in each homogeneous
        medium crossed, through ``null`` surfaces; 0 where any other surface is in the way."""
        tau = mi.Float(0.0)
        ray = _spawn_from(p, n, wo)
        med = medium
        open_ = mi.Bool(active)
        blocked = mi.Bool(False)
        k = mi.UInt32(0)
        while open_ & (k < self.SHADOW_CROSSINGS):
            si = scene.ray_intersect(ray, open_)
            has_med = open_ & (med != None)  # noqa: E711 (a MediumPtr compares with None)
            far = dr.select(si.is_valid(), si.t, 0.0)
            tau += dr.select(has_med & si.is_valid(),
                             self._sigma_t(med, ray.o, has_med) * far, 0.0)
            # escaping upward from inside a medium that has no top: nothing comes back
            blocked |= has_med & ~si.is_valid()
            null = si.is_valid() & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)
            blocked |= open_ & si.is_valid() & ~null
            med = dr.select(open_ & null, si.target_medium(wo), med)
            ray = dr.select(open_ & null, _spawn_from(si.p, si.n, wo), ray)
            open_ &= null
            k += 1
        blocked |= open_        # still crossing after SHADOW_CROSSINGS: treated as blocked
        return dr.select(active & ~blocked, dr.exp(-tau), 0.0)

    def _through_interface(self, scene, sampler, si_if, p, wo, medium, active):
        """The way out from ``p`` under a transmissive surface ``si_if`` (met straight toward
        the receiver along ``wo``): the surface's BSDF sampled from the receiver's side
        (``wi = wo``) gives the direction the light must travel up under it and the radiance
        it passes, f_t cos / pdf (Fresnel's T and the 1/n^2 of the radiance, in Mitsuba's
        radiance mode). A locally plane surface moves the crossing point along that
        direction. Returns ``(d_up, weight, dist_m, p_if, t_above)``: the direction, the
        weight times the transmittance of ``medium`` under the surface, the distance from
        ``p`` to the crossing [m], the crossing point, and the transmittance above it."""
        ctx = mi.BSDFContext()
        si = mi.SurfaceInteraction3f(si_if)
        si.wi = si.to_local(wo)
        bs, w = si.bsdf().sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active),
                                 active)
        d_in = si.to_world(bs.wo)                      # from the surface down into the water
        ok = (active & ((bs.sampled_type & _TRANSMISSION) != 0)
              & (dr.dot(d_in, si.n) < 0.0) & (w[0] > 0.0))
        d_up = -d_in
        # the plane through si.p: from p along d_up
        depth_n = dr.dot(si.p - p, si.n)
        dist_m = dr.select(ok, depth_n / dr.maximum(dr.dot(d_up, si.n), 1e-6), 0.0)
        p_if = p + d_up * dist_m
        tau = self._sigma_t(medium, p, ok & (medium != None)) * dist_m  # noqa: E711
        t_above = self._transmittance(scene, p_if, si.n, wo, si.target_medium(wo), ok)
        return d_up, dr.select(ok, w[0] * dr.exp(-tau), 0.0), dist_m, p_if, t_above

    def _next_event(self, scene, sampler, si, mei, medium, ray, p, scatter, surface, vertex,
                    throughput, n_g, phase, ssa, x0, y0, sx64, sy64):
        """The return toward the receiver from a vertex at ``p`` (a scattering, of the
        medium's ``phase`` function and single-scattering albedo ``ssa``, or a surface hit):
        its weight, and the float64 length [m] of its way up (delays included).
        Through ``null`` surfaces by transmittance; under a transmissive surface the way out
        is sampled at that surface (:meth:`_through_interface`)."""
        fov2 = self.fov_radius_m ** 2
        pctx = mi.PhaseFunctionContext(None)
        up_m = self._leg_m(p, sx64, sy64)
        wo = self._to_receiver(p, sx64, sy64, up_m)
        seen = vertex & (dr.square(p.x - x0) + dr.square(p.y - y0) <= fov2)
        # the medium on the receiver's side: a scattering's own; a surface's, on wo's side
        med_up = dr.select(scatter, medium, si.target_medium(wo))
        med_up = dr.select(surface & ~si.is_medium_transition(), medium, med_up)
        n_up = dr.select(scatter, mi.Vector3f(0.0), si.n)
        # under a transmissive surface (water): the way out is sampled at that surface
        # from the receiver's side (:meth:`_through_interface`); elsewhere a shadow ray
        si_up = scene.ray_intersect(_spawn_from(p, n_up, wo), seen)
        under = (seen & si_up.is_valid() & (dr.dot(si_up.n, wo) > 0.0)
                 & ((si_up.bsdf().flags() & _TRANSMISSION) != 0))
        d_out, w_if, dist_m, p_if, t_above = self._through_interface(
            scene, sampler, si_up, p, wo, med_up, under)
        d_ret = dr.select(under, d_out, wo)
        trans = dr.select(under, w_if * t_above,
                          self._transmittance(scene, p, n_up, wo, med_up, seen & ~under))
        ph_val, _ = phase.eval_pdf(pctx, mei, d_ret, scatter & seen)
        # an interface seen from below returns nothing itself: its light is counted at
        # the vertices under it
        from_below = surface & (dr.dot(ray.d, si.n) > 0.0) & (
            (si.bsdf().flags() & _TRANSMISSION) != 0)
        surf_w = self._return_weight(si, d_ret, surface & seen & ~from_below)
        value = dr.select(scatter, ssa * ph_val[0] * (dr.pi / REFERENCE_ALBEDO), surf_w)
        w = dr.select(seen, throughput * value * trans, 0.0)
        up_m = dr.select(under, self._leg_m(p_if, sx64, sy64)
                         + mi.Float64(dist_m * n_g), up_m)
        return w, up_m

    @dr.syntax
    def _media(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
               seed: mi.UInt32, z_start: mi.Float):
        """A symbolic loop over the events of each path (null crossings, volume
        scatterings, surface vertices). Returns Dr.Jit arrays of length ``n * max_depth``
        (slot ``lane * max_depth + vertex - 1``): time [ns] (float64), weight (0 where
        nothing returns), vertex x, y, z [m]."""
        n, depth_max, ng_table = dr.width(sx) * paths_per_shot, self.max_depth, self._ng
        lane = dr.arange(mi.UInt32, n)
        x0, y0, sampler, ray, t_emit_ns = self._emit(sx, sy, paths_per_shot, seed, z_start)
        sx64, sy64 = mi.Float64(x0), mi.Float64(y0)

        out = [dr.zeros(mi.Float64 if k == 0 else mi.Float, n * depth_max) for k in range(5)]
        # photons from the laser: importance mode (the 1/n^2 of radiance only on the way out)
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        pctx = mi.PhaseFunctionContext(None)
        medium = dr.zeros(mi.MediumPtr, n)           # above the scene: clear air
        n_g = mi.Float(1.0)                          # group index where the photon is
        throughput = mi.Float(1.0)
        down_m = mi.Float64(0.0)                     # spacecraft -> first vertex [m]
        inner_m = mi.Float64(0.0)                    # first vertex -> this one, delayed [m]
        p_prev = mi.Point3f(ray.o)
        depth = mi.UInt32(0)
        events = mi.UInt32(0)
        active = mi.Bool(True)

        while active & (depth < depth_max) & (events < 4 * depth_max + 16):
            si = scene.ray_intersect(ray, active)
            in_med = active & (medium != None)  # noqa: E711
            flight = mi.Ray3f(ray)
            flight.maxt = dr.select(si.is_valid(), si.t, dr.inf)
            mei = medium.sample_interaction(flight, sampler.next_1d(in_med), 0, in_med)
            scatter = in_med & mei.is_valid()
            hit = active & ~scatter & si.is_valid()
            null = hit & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)
            surface = hit & ~null
            vertex = scatter | surface
            p = dr.select(scatter, mei.p, si.p)
            seg = dr.norm(p - p_prev)
            # the path's length: the first vertex's float64 leg, then each segment delayed
            # by the group index of the region it crossed
            down_m = dr.select(vertex & (depth == 0), self._leg_m(p, sx64, sy64), down_m)
            inner_m += mi.Float64(dr.select(active & (depth > 0), seg * n_g, 0.0))
            p_prev = dr.select(active, p, p_prev)

            # -- next-event return toward the receiver
            phase = medium.phase_function()
            sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei, scatter)
            ssa = dr.select(scatter, sigma_s[0] / dr.maximum(sigma_t[0], 1e-30), 0.0)
            w, up_m = self._next_event(scene, sampler, si, mei, medium, ray, p, scatter,
                                       surface, vertex, throughput, n_g, phase, ssa,
                                       x0, y0, sx64, sy64)
            t_ns = mi.Float64(t_emit_ns) + (down_m + inner_m + up_m) / C_M_PER_NS
            slot = lane * depth_max + depth
            for target, val in zip(out, (t_ns, w, p.x, p.y, p.z)):
                dr.scatter(target, val, slot, vertex)

            # -- the next direction
            wo_ph, ph_w, _ = phase.sample(pctx, mei, sampler.next_1d(scatter),
                                          sampler.next_2d(scatter), scatter)
            bsdf = si.bsdf()
            bs, bsdf_w = bsdf.sample(ctx, si, sampler.next_1d(surface),
                                     sampler.next_2d(surface), surface)
            d_surf = si.to_world(bs.wo)
            # a refraction changes the region: into the interior against the normal
            refract = surface & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Transmission)
            bid = dr.reinterpret_array(mi.UInt32, bsdf)
            ng_in = dr.gather(mi.Float, ng_table, bid, refract)
            entering = dr.dot(d_surf, si.n) < 0.0
            n_g = dr.select(refract, dr.select(entering, ng_in, 1.0), n_g)
            d_new = dr.select(scatter, wo_ph, dr.select(surface, d_surf, ray.d))
            throughput *= dr.select(scatter, ssa * ph_w[0],
                                    dr.select(surface, bsdf_w[0], 1.0))
            medium = dr.select(hit & (null | (refract & si.is_medium_transition())),
                               si.target_medium(d_new), medium)
            n_off = dr.select(scatter, mi.Vector3f(0.0), si.n)
            ray = dr.select(active, _spawn_from(p, n_off, d_new), ray)
            depth += dr.select(vertex, 1, 0)
            events += 1
            active &= (scatter | hit) & (throughput > 0.0)
        return tuple(out)

    def to_string(self):
        return (f"MediaPathLengthIntegrator[max_depth={self.max_depth}, "
                f"altitude_m={self.altitude_m}]")


def _spawn_from(p: mi.Point3f, n: mi.Vector3f, d: mi.Vector3f) -> mi.Ray3f:
    """A ray from ``p`` toward ``d``, lifted off a surface of normal ``n`` (zero inside a
    medium: no lift) by (1 + max|p|) * 2^-20, as ``pathlength``'s spawn."""
    side = dr.select(dr.dot(n, d) >= 0.0, 1.0, -1.0)
    eps = (1.0 + dr.max(dr.abs(p))) * (2.0 ** -20)
    return mi.Ray3f(p + n * (side * eps), d)


mi.register_integrator("mediapathlength", lambda props: MediaPathLengthIntegrator(props))
