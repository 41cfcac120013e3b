"""Lidar path-length integrator as a Mitsuba 3 integrator plugin (``<integrator type="pathlength">``).

Registered in every JIT variant by ``import lidar_mitsuba``.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from lidar_mitsuba import constants as K
from lidar_mitsuba.constants import C_M_PER_NS, REFERENCE_ALBEDO
from lidar_mitsuba.photons import Returns
from lidar_mitsuba.scene import scene_bounds


class PathLengthIntegrator(mi.SamplingIntegrator):
    r"""
    Lidar path-length integrator (:monosp:`pathlength`)
    ---------------------------------------------------

    Traces the photons of a nadir-pointing, monostatic, pulsed lidar and records, per photon
    return, its shot, its round-trip time and its radiometric weight. It does not bin, detect or
    add noise: those are separate steps (``lidar_mitsuba.pmt``).

    .. pluginparameters::

     * - max_depth
       - |int|
       - Number of surface interactions per photon (default 1: the first-surface return,
         which for opaque terrain seen at nadir comes back along its own incident ray). With
         ``max_depth > 1`` each vertex adds a next-event return toward the receiver
         (shadow-tested), and the path continues by BSDF sampling: multiple scattering between
         terrain facets, on p = 1.8 fractal snow ~0.5 % of the return weight delayed by metres.
     * - altitude_m
       - |float|
       - Height of the spacecraft above the scene's z = 0 [m] (default 496 000).
     * - footprint_sigma_m
       - |float|
       - Standard deviation of the Gaussian footprint on the ground [m] (default 2.5, a 10 m
         1/e^2 diameter).
     * - pulse_sigma_ns
       - |float|
       - Standard deviation of the Gaussian pulse [ns] (default 1/2.3548: 1 ns FWHM).
     * - fov_radius_m
       - |float|
       - Receiver field-of-view radius on the ground [m] (default 20.65); returns from
         farther than this from the shot centre are not seen.
     * - max_lanes
       - |int|
       - Photons per Dr.Jit launch (default 2^23); longer tracks run in chunks of whole shots.

    Per photon, a footprint offset is drawn from the Gaussian around the shot centre, an
    emission time from the Gaussian pulse, and a ray is cast straight down from just above the
    scene's bounding box. The return weight of a vertex with incoming direction ``i`` and
    direction ``o`` toward the receiver is :math:`\pi f_r(i,o)\cos\theta_o / 0.9` times the path
    throughput, evaluated through the scene's BSDFs, so a flat Lambertian plate of albedo 0.9
    weighs 1. The return time is the exact two-way path length divided by c plus the emission
    time: the legs to and from the spacecraft are computed in float64, the rest in float32 in
    local scene coordinates, which keeps sub-millimetre precision at orbital range.

    ``sample()`` (used by ``mi.render`` with any sensor) returns the monostatic return weight of
    the first surface seen along a camera ray: a lidar-intensity image.

    .. tabs::

        .. code-tab:: xml

            <integrator type="pathlength">
                <integer name="max_depth" value="1"/>
                <float name="altitude_m" value="496000"/>
            </integrator>

        .. code-tab:: python

            {'type': 'pathlength', 'max_depth': 1, 'altitude_m': 496e3}
    """

    PARAMETERS = ("max_depth", "altitude_m", "footprint_sigma_m", "pulse_sigma_ns",
                  "fov_radius_m", "max_lanes")

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.max_depth = int(props.get("max_depth", 1))
        self.altitude_m = float(props.get("altitude_m", K.ALTITUDE_M))
        self.footprint_sigma_m = float(props.get("footprint_sigma_m",
                                                 K.FOOTPRINT_DIAMETER_M / 4.0))
        self.pulse_sigma_ns = float(props.get("pulse_sigma_ns",
                                              K.PULSE_FWHM_NS / K.FWHM_PER_SIGMA))
        self.fov_radius_m = float(props.get("fov_radius_m", K.FOV_DIAMETER_M / 2.0))
        self.max_lanes = int(props.get("max_lanes", 2 ** 23))
        #: the parameters the scene description set (simulate() honours them, see there)
        self.explicit = {name: getattr(self, name) for name in self.PARAMETERS if name in props}
        for name, value, ok in (
            ("max_depth", self.max_depth, 1 <= self.max_depth <= 64),
            ("altitude_m", self.altitude_m, 0 < self.altitude_m <= 1e8),
            ("footprint_sigma_m", self.footprint_sigma_m, 0 <= self.footprint_sigma_m <= 1e4),
            ("pulse_sigma_ns", self.pulse_sigma_ns, 0 <= self.pulse_sigma_ns <= 1e6),
            ("fov_radius_m", self.fov_radius_m, self.fov_radius_m > 0),
            ("max_lanes", self.max_lanes, 1 <= self.max_lanes <= 2 ** 30),
        ):
            if not ok:
                raise ValueError(f"pathlength: {name} out of range (got {value})")

    # ---------------------------------------------------------------- core
    def _return_weight(self, si: mi.SurfaceInteraction3f, wo_world: mi.Vector3f,
                       active: mi.Bool) -> mi.Float:
        """pi * f_r(i, o) * cos(theta_o) / 0.9 at ``si`` toward ``wo_world`` (no throughput)."""
        ctx = mi.BSDFContext()
        bsdf = si.bsdf()
        value = bsdf.eval(ctx, si, si.to_local(wo_world), active)
        return dr.select(active, dr.pi / REFERENCE_ALBEDO * value[0], 0.0)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        si = scene.ray_intersect(mi.Ray3f(ray), active)
        valid = si.is_valid() & active
        weight = self._return_weight(si, -ray.d, valid)
        return mi.Spectrum(weight), valid, []

    def _leg_m(self, p: mi.Point3f, sx: mi.Float64, sy: mi.Float64) -> mi.Float64:
        """Exact length [m] between the spacecraft (sx, sy, altitude) and p, in float64."""
        dx = mi.Float64(p.x) - sx
        dy = mi.Float64(p.y) - sy
        dz = mi.Float64(self.altitude_m) - mi.Float64(p.z)
        return dr.sqrt(dx * dx + dy * dy + dz * dz)

    def _to_receiver(self, p: mi.Point3f, sx: mi.Float64, sy: mi.Float64,
                     leg: mi.Float64) -> mi.Vector3f:
        return mi.Vector3f(mi.Float((sx - mi.Float64(p.x)) / leg),
                           mi.Float((sy - mi.Float64(p.y)) / leg),
                           mi.Float((mi.Float64(self.altitude_m) - mi.Float64(p.z)) / leg))

    @dr.syntax
    def _trace_chunk(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
                     seed: mi.UInt32, z_start: float):
        """Trace ``len(sx) * paths_per_shot`` photons. Returns Dr.Jit arrays of length
        ``n * max_depth``: local shot index, time [ns], weight, hit x, y, z [m]."""
        n_shots = dr.width(sx)
        n = n_shots * paths_per_shot
        depth_max = self.max_depth
        lane = dr.arange(mi.UInt32, n)
        shot = lane // paths_per_shot
        x0 = dr.gather(mi.Float, sx, shot)
        y0 = dr.gather(mi.Float, sy, shot)
        sx64, sy64 = mi.Float64(x0), mi.Float64(y0)

        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)
        # Gaussian footprint offset and emission time (Box-Muller).
        u = sampler.next_2d()
        r = self.footprint_sigma_m * dr.sqrt(-2.0 * dr.log(dr.maximum(1.0 - u.x, 1e-30)))
        sin_p, cos_p = dr.sincos(dr.two_pi * u.y)
        u = sampler.next_2d()
        t_emit_ns = (self.pulse_sigma_ns * dr.sqrt(-2.0 * dr.log(dr.maximum(1.0 - u.x, 1e-30)))
                     * dr.cos(dr.two_pi * u.y))

        ray = mi.Ray3f(mi.Point3f(x0 + r * cos_p, y0 + r * sin_p, z_start),
                       mi.Vector3f(0.0, 0.0, -1.0))
        si = scene.ray_intersect(ray)
        active = si.is_valid()
        down_m = self._leg_m(si.p, sx64, sy64)        # spacecraft -> first vertex [m], float64
        inner_m = mi.Float(0.0)                        # between vertices, local float32 [m]
        throughput = mi.Float(1.0)

        out_w = dr.zeros(mi.Float, n * depth_max)
        out_t = dr.zeros(mi.Float64, n * depth_max)
        out_x = dr.zeros(mi.Float, n * depth_max)
        out_y = dr.zeros(mi.Float, n * depth_max)
        out_z = dr.zeros(mi.Float, n * depth_max)
        fov2 = self.fov_radius_m ** 2
        ctx = mi.BSDFContext()
        depth = mi.UInt32(0)

        while active & (depth < depth_max):
            up_m = self._leg_m(si.p, sx64, sy64)
            wo = self._to_receiver(si.p, sx64, sy64, up_m)
            seen = active & (dr.square(si.p.x - x0) + dr.square(si.p.y - y0) <= fov2)
            if depth > 0:   # the first vertex returns along its own incident ray: unoccluded
                seen &= ~scene.ray_test(_spawn(si, wo), seen)
            w = throughput * self._return_weight(si, wo, seen)
            t_ns = mi.Float64(t_emit_ns) + (down_m + mi.Float64(inner_m) + up_m) / C_M_PER_NS
            slot = lane * depth_max + depth
            dr.scatter(out_w, w, slot, active)
            dr.scatter(out_t, t_ns, slot, active)
            dr.scatter(out_x, si.p.x, slot, active)
            dr.scatter(out_y, si.p.y, slot, active)
            dr.scatter(out_z, si.p.z, slot, active)

            depth += 1
            if depth < depth_max:
                bsdf = si.bsdf()
                bs, bsdf_w = bsdf.sample(ctx, si, sampler.next_1d(active),
                                         sampler.next_2d(active), active)
                throughput *= bsdf_w[0]
                ray = _spawn(si, si.to_world(bs.wo))
                p_prev = mi.Point3f(si.p)
                si = scene.ray_intersect(ray, active)
                # vertex to vertex, not si.t: the ray starts off the surface
                inner_m += dr.select(si.is_valid(), dr.norm(si.p - p_prev), 0.0)
                active &= si.is_valid() & (throughput > 0)
        shot_out = dr.arange(mi.UInt32, n * depth_max) // (paths_per_shot * depth_max)
        return shot_out, out_t, out_w, out_x, out_y, out_z

    # ---------------------------------------------------------------- public
    def trace(self, scene: mi.Scene, *, shot_x_m: np.ndarray, shot_y_m: np.ndarray,
              paths_per_shot: int = 128, seed: int = 0, keep_zero_weight: bool = False,
              progress=None) -> Returns:
        """Trace ``paths_per_shot`` photons for every shot.

        Args:
            scene: the Mitsuba scene (terrain in local coordinates, z up, metres).
            shot_x_m, shot_y_m: (n_shots,) footprint centres [m] in scene coordinates.
            paths_per_shot: photon paths traced per shot (Monte Carlo samples of the return).
            seed: random seed; the same seed gives the same photons.
            keep_zero_weight: keep returns of weight 0 (misses are always dropped).
            progress: optional callable ``progress(n_shots_done)`` called after each chunk.

        Returns:
            :class:`~lidar_mitsuba.photons.Returns`, one entry per photon return (at most
            ``n_shots * paths_per_shot * max_depth``), sorted by shot: ``shot`` (uint32),
            ``time_ns`` (float64 round-trip time [ns] from the pulse centre's emission),
            ``weight`` (float32), ``x_m``, ``y_m``, ``z_m`` (float32 vertex position [m]),
            ``depth`` (uint8, 1 = first surface).
        """
        shot_x_m = np.ascontiguousarray(shot_x_m, dtype=np.float32).ravel()
        shot_y_m = np.ascontiguousarray(shot_y_m, dtype=np.float32).ravel()
        if shot_x_m.shape != shot_y_m.shape:
            raise ValueError("shot_x_m and shot_y_m must have the same shape")
        if paths_per_shot < 1:
            raise ValueError(f"paths_per_shot must be >= 1 (got {paths_per_shot})")
        n_shots = shot_x_m.size
        lo, hi = scene_bounds(scene)
        z_start = float(hi[2]) + 1e-3 * max(float(hi[2] - lo[2]), 1.0) + 1e-2
        if not (z_start < self.altitude_m):
            raise ValueError(f"altitude_m ({self.altitude_m}) must be above the scene top "
                             f"({float(hi[2])})")
        per_chunk = max(1, self.max_lanes // (paths_per_shot * self.max_depth))
        parts: list[tuple[Returns, int]] = []
        for k, start in enumerate(range(0, n_shots, per_chunk)):
            stop = min(n_shots, start + per_chunk)
            chunk_seed = dr.opaque(mi.UInt32, _mix_seed(seed, k))
            shot, t, w, x, y, z = self._trace_chunk(
                scene, mi.Float(shot_x_m[start:stop]), mi.Float(shot_y_m[start:stop]),
                paths_per_shot, chunk_seed, z_start)
            dr.eval(shot, t, w, x, y, z)
            w_np = w.numpy()
            t_np = t.numpy()
            keep = (w_np > 0) if not keep_zero_weight else (t_np > 0)
            depth = (np.arange(w_np.size) % self.max_depth + 1).astype(np.uint8)
            parts.append((Returns(
                shot=shot.numpy()[keep], time_ns=t_np[keep], weight=w_np[keep],
                x_m=x.numpy()[keep], y_m=y.numpy()[keep], z_m=z.numpy()[keep],
                depth=depth[keep], n_shots=stop - start, paths_per_shot=int(paths_per_shot)),
                start))
            if progress is not None:
                progress(stop - start)
        if not parts:
            return Returns.empty(n_shots=0, paths_per_shot=paths_per_shot)
        if len(parts) == 1:
            return parts[0][0]
        out = Returns.concatenate(parts, n_shots=n_shots)
        out.shot = out.shot.astype(np.uint32)
        return out

    def to_string(self):
        return (f"PathLengthIntegrator[max_depth={self.max_depth}, altitude_m={self.altitude_m}, "
                f"footprint_sigma_m={self.footprint_sigma_m}, "
                f"pulse_sigma_ns={self.pulse_sigma_ns}]")


def _spawn(si: mi.SurfaceInteraction3f, d: mi.Vector3f) -> mi.Ray3f:
    """A ray from ``si.p`` toward ``d``, lifted off the surface along the geometric normal by
    (1 + max|p|) * 2^-20 (about 16 float32 steps of the coordinates). Mitsuba's
    ``spawn_ray`` lifts by (1 + max|p|) * 8.9e-5, which is 9 cm at 1 km from the scene origin
    (where the built-in tiles put their tracks): enough to start a bounce behind the facing
    slope of a groove and lose 13 % of the double-bounce return (tests/test_multibounce.py)."""
    side = dr.select(dr.dot(si.n, d) >= 0.0, 1.0, -1.0)
    eps = (1.0 + dr.max(dr.abs(si.p))) * (2.0 ** -20)
    return mi.Ray3f(si.p + si.n * (side * eps), d)


def _mix_seed(seed: int, chunk: int) -> int:
    """A 32-bit seed per (seed, chunk) pair (splitmix-style hash)."""
    z = (int(seed) * 0x9E3779B97F4A7C15 + int(chunk) * 0xBF58476D1CE4E5B9 + 0x94D049BB133111EB)
    z &= 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return int((z ^ (z >> 31)) & 0xFFFFFFFF)


mi.register_integrator("pathlength", lambda props: PathLengthIntegrator(props))
