"""Lidar path-length integrator with a participating medium (``<integrator type="volpathlength">``).

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``),
after ``pathlength``, on which it builds.
"""
from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi

from lidar_mitsuba_plugins.constants import C_M_PER_NS, REFERENCE_ALBEDO
from lidar_mitsuba_plugins.scene_utils import scene_medium

_pathlength = sys.modules[f"lidar_mitsuba_plugins._{mi.variant()}_pathlength"]


class VolumePathLengthIntegrator(_pathlength.PathLengthIntegrator):
    r"""
    Lidar path-length integrator with volume scattering (:monosp:`volpathlength`)
    -----------------------------------------------------------------------------

    The ``pathlength`` integrator for scenes with a participating medium: snow under the
    terrain (:mod:`lidar_mitsuba.ground.snow`). The medium is the interior of a shape with a
    ``null`` BSDF (an index-matched boundary), homogeneous, with any Mitsuba phase function.

    .. pluginparameters::

     * - max_depth
       - |int|
       - Interactions per photon: volume scatterings and opaque-surface hits (default 10000).
         A photon still travelling after that is dropped (its later returns are lost).
     * - group_index
       - |float|
       - Delay per metre of path inside the medium relative to air (default 1): the snow's
         group index, ``1 + (n_ice - 1) rho / rho_ice``.
     * - snow_depth_m
       - |float|
       - Thickness of the medium under its surface, measured vertically [m] (default inf:
         semi-infinite).
     * - base_albedo
       - |float|
       - Lambertian albedo of the opaque base under a finite layer (default 0).
     * - crust_m, crust_sigma_t, crust_albedo, crust_g, crust_group_index
       - |float|
       - A denser surface layer (wind crust), ``crust_m`` thick measured vertically
         (default 0: none), with its own extinction [1/m], single-scattering albedo, HG
         asymmetry and group index, over the scene's medium. Free paths end at the interface
         and go on in the other layer (exact for exponential free paths).
     * - tally
       - |string|
       - ``receiver`` (default): next-event returns toward the receiver, as above.
         ``hemisphere``: instead, the light leaving the medium in any direction, recorded
         where it leaves through the surface with its throughput as weight (the snow's
         hemispherical albedo and its path lengths, what diffusion theory predicts; no
         lidar meaning).
     * - (others)
       - as ``pathlength``: ``altitude_m``, ``footprint_sigma_m``, ``pulse_sigma_ns``,
         ``fov_radius_m``, ``max_lanes``.

    A photon whose first surface is opaque returns as in ``pathlength`` (single bounce). One
    that meets the medium's boundary enters it (index-matched: no refraction, no reflection)
    and random-walks below the plane of the facet it entered through: free paths sampled by
    the medium (``Medium.sample_interaction``), new directions by its phase function, its
    throughput times the single-scattering albedo at each scattering. A finite layer
    (``snow_depth_m``) ends at a Lambertian base that far below the surface; the walk ends
    when the photon leaves through the surface or after ``max_depth`` interactions.

    At every interaction a next-event return toward the receiver is estimated: the phase
    function (or the base's :math:`f_r \cos\theta_o`) times the transmittance
    :math:`e^{-\sigma_t s}` along the path ``s`` to the surface, weighted
    :math:`\pi\,\varpi\,p(i, o)\,T / 0.9` so that the weights keep the surface
    integrator's scale (a flat Lambertian 0.9 plate weighs 1). Its delay is the path inside
    the medium times ``group_index`` plus the float64 legs to and from the spacecraft.

    Why a plane and not the mesh: snow's free path (0.1-1 mm) is at the float32 rounding of
    hit distances on a kilometre-sized mesh (~1e-4 m), so walking against the mesh puts
    photons on the wrong side of the surface (a first version did: 1 % of the single
    scattering lost on a plane 1 km across, 28 % at 100 km); in the entry facet's frame the walk is exact
    to ~1e-9 m. A returned photon travels centimetres sideways, far less than the 1 m
    facets, and light that leaves the snow does not come back to other terrain (no
    facet-to-facet bounce, nor shadowing of the return: it leaves within centimetres of
    where it entered, along the direction it came from).

    The walk runs in stages of 512, 4096, ... interactions; between stages only the photons
    still walking go on, compacted, with a fresh random stream (the path-length tail is heavy:
    without this, each packet of lanes waits for its longest walk; 2-3.7x faster on CPU).

    One record per photon: the path's returns are summed, and one of them, drawn in
    proportion to its weight (a one-slot weighted reservoir), gives the record's time and
    position. Its weight is the sum, so the weighted time distribution is unbiased while
    memory stays one slot per photon for paths of thousands of scatterings. ``depth`` is the
    number of interactions before the drawn return (capped at 255).

    .. tabs::

        .. code-tab:: xml

            <integrator type="volpathlength">
                <integer name="max_depth" value="10000"/>
                <float name="group_index" value="1.12"/>
            </integrator>

        .. code-tab:: python

            {'type': 'volpathlength', 'max_depth': 10000, 'group_index': 1.12}
    """

    #: parameters beyond ``pathlength``'s
    VOLUME_PARAMETERS = ("group_index", "snow_depth_m", "base_albedo", "tally", "crust_m",
                         "crust_sigma_t", "crust_albedo", "crust_g", "crust_group_index")

    def __init__(self, props: mi.Properties):
        if "max_depth" not in props:
            props["max_depth"] = 10000
        depth = int(props["max_depth"])
        if not 1 <= depth <= 10 ** 7:
            raise ValueError(f"volpathlength: max_depth out of range (got {depth})")
        props["max_depth"] = min(depth, 64)            # the base class's own range check
        super().__init__(props)
        self.max_depth = depth
        if "max_depth" in self.explicit:
            self.explicit["max_depth"] = depth
        self.group_index = float(props.get("group_index", 1.0))
        self.snow_depth_m = float(props.get("snow_depth_m", float("inf")))
        self.base_albedo = float(props.get("base_albedo", 0.0))
        self.tally = str(props.get("tally", "receiver"))
        self.crust_m = float(props.get("crust_m", 0.0))
        self.crust_sigma_t = float(props.get("crust_sigma_t", 1.0))
        self.crust_albedo = float(props.get("crust_albedo", 1.0))
        self.crust_g = float(props.get("crust_g", 0.0))
        self.crust_group_index = float(props.get("crust_group_index", 1.0))
        for name, ok in (("group_index", 1.0 <= self.group_index <= 2.0),
                         ("snow_depth_m", self.snow_depth_m > 0),
                         ("base_albedo", 0.0 <= self.base_albedo <= 1.0),
                         ("tally", self.tally in ("receiver", "hemisphere")),
                         ("crust_m", 0.0 <= self.crust_m < self.snow_depth_m),
                         ("crust_sigma_t", self.crust_sigma_t > 0.0),
                         ("crust_albedo", 0.0 <= self.crust_albedo <= 1.0),
                         ("crust_g", -1.0 < self.crust_g < 1.0),
                         ("crust_group_index", 1.0 <= self.crust_group_index <= 2.0)):
            if not ok:
                raise ValueError(f"volpathlength: {name} out of range "
                                 f"(got {getattr(self, name)!r})")
        self.explicit.update({k: getattr(self, k) for k in self.VOLUME_PARAMETERS if k in props})
        self._medium = None
        self._crust_phase = (mi.load_dict({"type": "hg", "g": self.crust_g})
                             if self.crust_m > 0 else None)

    def _core(self, scene: mi.Scene):
        self._medium = scene_medium(scene)
        return self._volume, 1

    def _volume(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
                seed: mi.UInt32, z_start: mi.Float):
        """Per photon: the first surface; an opaque one returns as in ``pathlength``
        (single bounce), the medium's boundary starts a random walk below its tangent plane
        (a symbolic loop). Returns Dr.Jit arrays of length ``n`` (one slot per photon): time
        [ns] (float64) and position [m] of the drawn return, the summed weight (0 where
        nothing returns), and its interaction count."""
        medium = self._medium
        x0, y0, sampler, ray, t_emit_ns, si, down_m, wo0, in_fov = self._first_hit(
            scene, sx, sy, paths_per_shot, seed, z_start)
        # an opaque first surface: the single-bounce return
        null = si.is_valid() & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)
        opaque = in_fov & ~null
        w_sum = self._return_weight(si, wo0, opaque)
        rec_t = mi.Float64(t_emit_ns) + (down_m + down_m) / C_M_PER_NS
        rec_x, rec_y, rec_z = mi.Float(si.p.x), mi.Float(si.p.y), mi.Float(si.p.z)
        rec_d = dr.select(opaque, mi.UInt32(1), mi.UInt32(0))
        if medium is None:
            return rec_t, w_sum, rec_x, rec_y, rec_z, rec_d
        state = {
            # per photon, fixed: the entry point and facet normal (the walk's frame), the
            # direction to the receiver, the shot centre, the down leg, the emission time
            "entry": mi.Point3f(si.p), "n": mi.Vector3f(si.n), "wo": mi.Vector3f(wo0),
            "x0": mi.Float(x0), "y0": mi.Float(y0), "down_m": mi.Float64(down_m),
            "t_emit": mi.Float(t_emit_ns),
            # the walk: position in the entry frame, direction, optical path, throughput
            "q": mi.Vector3f(0.0), "d": mi.Vector3f(ray.d), "path_m": mi.Float64(0.0),
            "throughput": mi.Float(1.0), "events": mi.UInt32(0),
            "active": null & (dr.dot(ray.d, si.n) < 0.0),
            "in_crust": null & (self.crust_m > 0),        # the layer it is in
            # the record (one-slot weighted reservoir)
            "rec_t": rec_t, "w_sum": w_sum, "rec_x": rec_x, "rec_y": rec_y, "rec_z": rec_z,
            "rec_d": rec_d}
        return self._walk(medium, state, sampler, seed)

    #: interactions of the first stage of the walk; each later stage allows 8 times more
    STAGE_EVENTS = 512
    _RECORD = ("rec_t", "w_sum", "rec_x", "rec_y", "rec_z", "rec_d")

    def _walk(self, medium, state: dict, sampler, seed):
        """The random walk of the photons that entered the medium, in stages: each stage
        runs the loop (:meth:`_walk_loop`) up to an interaction limit, then only the photons
        still walking go on, compacted (``dr.compress``), with a fresh random stream. A
        vectorised loop runs until the last lane of its packet (or warp) is done, and a few
        photons of every packet walk 100 times longer than the median one: compaction keeps
        the long walks from holding whole packets. Returns the records of every photon."""
        out = None
        idx = None
        limit = min(self.STAGE_EVENTS, self.max_depth)
        stage = 0
        while True:
            state = self._walk_loop(medium, state, sampler, dr.opaque(mi.UInt32, limit))
            if limit < self.max_depth:
                # one kernel for all of the loop's outputs: evaluated one by one (compress,
                # then the gathers), each would run the loop again
                dr.eval(state)
            if out is None:
                out = {k: state[k] for k in self._RECORD}
            else:
                for k in self._RECORD:
                    dr.scatter(out[k], state[k], idx)
            if limit >= self.max_depth:
                break
            more = dr.compress(state["active"])          # photons still walking
            if dr.width(more) == 0:
                break
            idx = more if idx is None else dr.gather(mi.UInt32, idx, more)
            state = {k: dr.gather(type(v), v, more) for k, v in state.items()}
            stage += 1
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(seed + mi.UInt32(0x9E3779B9 * stage & 0xFFFFFFFF), dr.width(more))
            limit = min(limit * 8, self.max_depth)
        return tuple(out[k] for k in self._RECORD)

    @dr.syntax
    def _walk_loop(self, medium, state: dict, sampler, limit: mi.UInt32) -> dict:
        """The walk of each photon (a symbolic loop) until it leaves, is absorbed or reaches
        ``limit`` interactions (then ``active`` stays set: it goes on in the next stage)."""
        entry, n, wo = state["entry"], state["n"], state["wo"]
        x0, y0, down_m, t_emit_ns = state["x0"], state["y0"], state["down_m"], state["t_emit"]
        q, d, path_m = state["q"], state["d"], state["path_m"]
        throughput, events, active = state["throughput"], state["events"], state["active"]
        in_crust = state["in_crust"]
        rec_t, w_sum, rec_x, rec_y, rec_z, rec_d = (state[k] for k in self._RECORD)
        sx64, sy64 = mi.Float64(x0), mi.Float64(y0)
        fov2 = self.fov_radius_m ** 2
        # the walk, in a frame at the entry point: q = position - entry [m], float32 (exact
        # to ~1e-9 m over a walk), below the entry facet's plane (normal n) while q.n < 0;
        # a finite layer ends at the base plane, depth_m below it vertically
        # opaque: another snowpack (density, depth, base) reuses the compiled walk
        base_n = -dr.opaque(mi.Float, self.snow_depth_m) * dr.abs(n.z)   # q.n of the base
        n_g = dr.opaque(mi.Float, self.group_index)
        pctx = mi.PhaseFunctionContext(None)
        # the direction to the receiver is the same for every vertex of a walk (to 1e-7 rad)
        wo_n = dr.dot(wo, n)
        hemisphere = self.tally == "hemisphere"
        base_albedo = dr.opaque(mi.Float, self.base_albedo)
        layers = _Layers(self, medium, n, wo_n, base_n, n_g)

        while active & (events < limit):
            # -- the flight: to the surface (up), to the base (down), to the interface of a
            # crust, or a scattering (the medium's free path, scaled in a crust)
            t_top, t_base, t_if, scale, ng_here = layers.walls(q, d, in_crust)
            t_wall = dr.minimum(dr.minimum(t_top, t_base), t_if)
            flight = mi.Ray3f(mi.Point3f(q), d)
            flight.maxt = t_wall * scale
            mei = medium.sample_interaction(flight, sampler.next_1d(active), 0, active)
            scatter = active & mei.is_valid()
            out = active & ~scatter & (t_top <= t_base) & (t_top <= t_if)
            on_base = active & ~scatter & (t_base < t_top) & (t_base <= t_if)
            cross = active & ~scatter & (t_if < t_top) & (t_if < t_base)
            step = dr.select(scatter, mei.t / scale, t_wall)
            path_m += mi.Float64(dr.select(active, step * ng_here, 0.0))
            q = dr.select(active, q + d * step, q)
            vertex = scatter | on_base
            events += dr.select(vertex, 1, 0)

            # -- the return toward the receiver from this vertex: out through the top plane
            ph_val, ssa = layers.phase_eval(pctx, mei, wo, scatter, in_crust)
            t_up, tau_up, delay_up = layers.up_leg(q, mei, active, in_crust)
            value = dr.select(scatter, ssa * ph_val,
                              base_albedo * dr.maximum(wo_n, 0.0) * dr.inv_pi)
            p_exit = entry + q + wo * t_up
            seen = (vertex & (wo_n > 0.0)
                    & (dr.square(p_exit.x - x0) + dr.square(p_exit.y - y0) <= fov2))
            w = dr.select(seen, throughput * value * dr.exp(-tau_up)
                          * (dr.pi / REFERENCE_ALBEDO), 0.0)
            leg_up = self._leg_m(p_exit, sx64, sy64) + mi.Float64(delay_up)
            at = entry + q
            if hemisphere:                     # light crossing the surface outward
                seen = out
                w = dr.select(out, throughput, 0.0)
                leg_up = self._leg_m(at, sx64, sy64)
            t_ns = mi.Float64(t_emit_ns) + (down_m + path_m + leg_up) / C_M_PER_NS
            # one-slot weighted reservoir: keep this return with probability w / w_sum
            w_sum += w
            keep = seen & (sampler.next_1d(active) * w_sum < w)
            rec_t = dr.select(keep, t_ns, rec_t)
            rec_x = dr.select(keep, at.x, rec_x)
            rec_y = dr.select(keep, at.y, rec_y)
            rec_z = dr.select(keep, at.z, rec_z)
            rec_d = dr.select(keep, events, rec_d)

            # -- the next flight: phase function, or a Lambertian base (cosine-weighted)
            u1, u2 = sampler.next_1d(active), sampler.next_2d(active)
            wo_ph, ph_w = layers.phase_sample(pctx, mei, u1, u2, scatter, in_crust)
            up = mi.Frame3f(n).to_world(mi.warp.square_to_cosine_hemisphere(
                sampler.next_2d(active)))
            d = dr.select(scatter, wo_ph, dr.select(on_base, up, d))
            throughput *= dr.select(scatter, ssa * ph_w, dr.select(on_base, base_albedo, 1.0))
            in_crust = dr.select(cross, ~in_crust, in_crust)
            active &= (vertex | cross) & (throughput > 0.0)
        return dict(state, q=q, d=d, path_m=path_m, throughput=throughput, events=events,
                    active=active, in_crust=in_crust, rec_t=rec_t, w_sum=w_sum, rec_x=rec_x,
                    rec_y=rec_y, rec_z=rec_z, rec_d=rec_d)

    def to_string(self):
        return (f"VolumePathLengthIntegrator[max_depth={self.max_depth}, "
                f"group_index={self.group_index}, altitude_m={self.altitude_m}]")


class _Layers:
    """The snowpack's layers as the walk meets them, in the entry facet's frame (normal
    ``n``, position ``q``): the pack over its base, and a crust on top (``crust_m`` > 0,
    decided in Python: the walk without one compiles as before). The crust's free paths are
    the medium's own, scaled by the ratio of extinctions (homogeneous layers: the same
    exponential law in optical depth), so one ``sample_interaction`` serves both layers."""

    def __init__(self, integ: VolumePathLengthIntegrator, medium, n, wo_n, base_n, n_g):
        self.medium, self.n, self.wo_n, self.base_n, self.n_g = medium, n, wo_n, base_n, n_g
        self.crust = integ.crust_m > 0
        if self.crust:
            self.phase_c = integ._crust_phase
            self.iface_n = -dr.opaque(mi.Float, integ.crust_m) * dr.abs(n.z)  # its q.n
            self.st_c = dr.opaque(mi.Float, integ.crust_sigma_t)
            self.alb_c = dr.opaque(mi.Float, integ.crust_albedo)
            self.ng_c = dr.opaque(mi.Float, integ.crust_group_index)
            self.st_l = medium.get_scattering_coefficients(
                dr.zeros(mi.MediumInteraction3f), True)[2][0]
            self.s_iface = -self.iface_n / dr.maximum(wo_n, 1e-30)   # the crust along wo

    def walls(self, q, d, in_crust):
        """Distances [m] along ``d`` to the top, the base and a crust's interface (inf where
        not a wall of the photon's layer), the free-path scale and the group index there."""
        qn, dn = dr.dot(q, self.n), dr.dot(d, self.n)
        t_top = dr.select(dn > 0.0, -qn / dr.maximum(dn, 1e-30), dr.inf)
        t_base = dr.select(dn < 0.0, (self.base_n - qn) / dr.minimum(dn, -1e-30), dr.inf)
        if not self.crust:
            return t_top, t_base, mi.Float(dr.inf), mi.Float(1.0), self.n_g
        # the interface is a wall only on the way out of the photon's layer (a photon just
        # across it, by rounding, crosses at once: a zero step)
        down = dr.maximum((self.iface_n - qn) / dr.minimum(dn, -1e-30), 0.0)
        up = dr.maximum((self.iface_n - qn) / dr.maximum(dn, 1e-30), 0.0)
        t_if = dr.select(in_crust, dr.select(dn < 0.0, down, dr.inf),
                         dr.select(dn > 0.0, up, dr.inf))
        return (dr.select(in_crust, t_top, dr.inf), dr.select(in_crust, dr.inf, t_base), t_if,
                dr.select(in_crust, self.st_c / self.st_l, 1.0),
                dr.select(in_crust, self.ng_c, self.n_g))

    def phase_eval(self, pctx, mei, wo, scatter, in_crust):
        """The phase function toward ``wo`` and the single-scattering albedo at a vertex."""
        ph, _ = self.medium.phase_function().eval_pdf(pctx, mei, wo, scatter & ~in_crust)
        sigma_s, _, sigma_t = self.medium.get_scattering_coefficients(mei, scatter)
        ph, ssa = ph[0], sigma_s[0] / sigma_t[0]
        if self.crust:
            ph_c, _ = self.phase_c.eval_pdf(pctx, mei, wo, scatter & in_crust)
            ph, ssa = dr.select(in_crust, ph_c[0], ph), dr.select(in_crust, self.alb_c, ssa)
        return ph, ssa

    def up_leg(self, q, mei, active, in_crust):
        """From ``q`` out through the top along the receiver's direction: its length [m],
        optical depth and delay (the group indices of the layers it crosses) [m]."""
        _, _, sigma_t = self.medium.get_scattering_coefficients(mei, active)
        t_up = dr.select(self.wo_n > 0.0, -dr.dot(q, self.n) / dr.maximum(self.wo_n, 1e-30),
                         0.0)
        if not self.crust:
            return t_up, sigma_t[0] * t_up, t_up * self.n_g
        s_c = dr.select(in_crust, t_up, dr.minimum(self.s_iface, t_up))
        return (t_up, self.st_c * s_c + self.st_l * (t_up - s_c),
                self.ng_c * s_c + self.n_g * (t_up - s_c))

    def phase_sample(self, pctx, mei, u1, u2, scatter, in_crust):
        """The next direction at a scattering and its phase weight."""
        wo_ph, ph_w, _ = self.medium.phase_function().sample(pctx, mei, u1, u2,
                                                             scatter & ~in_crust)
        if self.crust:
            wo_c, ph_wc, _ = self.phase_c.sample(pctx, mei, u1, u2, scatter & in_crust)
            wo_ph, ph_w = dr.select(in_crust, wo_c, wo_ph), dr.select(in_crust, ph_wc, ph_w)
        return wo_ph, ph_w[0]


mi.register_integrator("volpathlength", lambda props: VolumePathLengthIntegrator(props))
