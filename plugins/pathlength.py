"""Lidar path-length integrator as a Mitsuba 3 integrator plugin (``<integrator type="pathlength">``).

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``).
"""
from __future__ import annotations

import time

import drjit as dr
import mitsuba as mi
import numpy as np

from lidar_mitsuba_plugins import constants as K
from lidar_mitsuba_plugins.constants import C_M_PER_NS, REFERENCE_ALBEDO
from lidar_mitsuba_plugins.returns import Returns
from lidar_mitsuba_plugins.scene_utils import scene_bounds, scene_medium


class PathLengthIntegrator(mi.SamplingIntegrator):
    r"""
    Lidar path-length integrator (:monosp:`pathlength`)
    ---------------------------------------------------

    Traces the photons of a nadir-pointing, monostatic, pulsed lidar and records, per photon
    return, its shot, its round-trip time and its radiometric weight. It does not bin, detect or
    add noise: those are separate steps (in the lidar pipeline, ``lidar_mitsuba.detector.pmt``).

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
                       active: mi.Bool, bsdf: mi.BSDF | None = None) -> mi.Float:
        """pi * f_r(i, o) * cos(theta_o) / 0.9 at ``si`` toward ``wo_world`` (no throughput),
        of ``bsdf`` (a lone mesh's, :func:`_lone_mesh`: in line) or else ``si.bsdf()``."""
        ctx = mi.BSDFContext()
        if bsdf is None:
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

    def _emit(self, sx: mi.Float, sy: mi.Float, paths_per_shot: int, seed: mi.UInt32,
              z_start: mi.Float):
        """The photons of ``len(sx)`` shots: per lane its shot, the shot centre, the sampler
        (seeded), the first ray and the emission time [ns]."""
        n = dr.width(sx) * paths_per_shot
        # opaque: one kernel serves every paths_per_shot (paths_per_shot="auto" varies it)
        shot = _quotient(dr.arange(mi.UInt32, n), paths_per_shot)
        x0 = dr.gather(mi.Float, sx, shot)
        y0 = dr.gather(mi.Float, sy, shot)
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
        return x0, y0, sampler, ray, t_emit_ns

    def _first_hit(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
                   seed: mi.UInt32, z_start: mi.Float, mesh: mi.Mesh | None = None):
        """Emit the photons (:meth:`_emit`) and find their first surface (``mesh``: the
        scene's lone mesh, its interaction in line: :func:`_mesh_interaction`). Returns
        ``(x0, y0, sampler, ray, t_emit_ns, si, leg_m, wo, in_fov)``: :meth:`_emit`'s, the
        interaction, the float64 leg between the spacecraft and it [m], the direction to
        the receiver, and whether it is a hit inside the field of view."""
        x0, y0, sampler, ray, t_emit_ns = self._emit(sx, sy, paths_per_shot, seed, z_start)
        sx64, sy64 = mi.Float64(x0), mi.Float64(y0)
        si = scene.ray_intersect(ray) if mesh is None else _mesh_interaction(scene, mesh, ray)
        leg_m = self._leg_m(si.p, sx64, sy64)     # the same leg down and up, float64
        wo = self._to_receiver(si.p, sx64, sy64, leg_m)
        in_fov = si.is_valid() & (dr.square(si.p.x - x0) + dr.square(si.p.y - y0)
                                  <= self.fov_radius_m ** 2)
        return x0, y0, sampler, ray, t_emit_ns, si, leg_m, wo, in_fov

    def _first_surface(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
                       seed: mi.UInt32, z_start: mi.Float):
        """``max_depth == 1``: one return per photon, straight-line code (no loop, no
        scatter). Returns Dr.Jit arrays of length ``n`` (one slot per photon): time [ns]
        (float64), weight (0 where nothing returns), hit x, y, z [m]. A scene of one mesh
        (a corridor tile) skips the shape and BSDF registries' calls (:func:`_lone_mesh`)."""
        mesh = _lone_mesh(scene)
        *_, t_emit_ns, si, leg_m, wo, seen = self._first_hit(scene, sx, sy, paths_per_shot,
                                                             seed, z_start, mesh=mesh)
        w = self._return_weight(si, wo, seen, None if mesh is None else mesh.bsdf())
        t_ns = mi.Float64(t_emit_ns) + (leg_m + leg_m) / C_M_PER_NS
        return t_ns, w, si.p.x, si.p.y, si.p.z

    @dr.syntax
    def _multi_bounce(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
                      seed: mi.UInt32, z_start: mi.Float):
        """``max_depth > 1``: a symbolic loop over the vertices of each path. Returns Dr.Jit
        arrays of length ``n * max_depth`` (slot ``lane * max_depth + depth - 1``): time [ns]
        (float64), weight (0 where nothing returns), hit x, y, z [m]."""
        n = dr.width(sx) * paths_per_shot
        depth_max = self.max_depth
        lane = dr.arange(mi.UInt32, n)
        x0, y0, sampler, ray, t_emit_ns = self._emit(sx, sy, paths_per_shot, seed, z_start)
        sx64, sy64 = mi.Float64(x0), mi.Float64(y0)
        si = scene.ray_intersect(ray)
        active = si.is_valid()
        down_m = self._leg_m(si.p, sx64, sy64)        # spacecraft -> first vertex [m], float64
        inner_m = mi.Float(0.0)                        # between vertices, local float32 [m]
        throughput = mi.Float(1.0)

        out = [dr.zeros(mi.Float64 if k == 0 else mi.Float, n * depth_max) for k in range(5)]
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
            for target, value in zip(out, (t_ns, w, si.p.x, si.p.y, si.p.z)):
                dr.scatter(target, value, slot, active)

            depth += 1
            if depth < depth_max:
                bsdf = si.bsdf()
                bs, bsdf_w = bsdf.sample(ctx, si, sampler.next_1d(active),
                                         sampler.next_2d(active), active)
                throughput *= bsdf_w[0]
                ray = _spawn(si, si.to_world(bs.wo))
                # The last vertex only counts inside the field of view: its ray stops where
                # it leaves the FOV cylinder (it can leave the scene early, and most do).
                ray.maxt = dr.select(depth == depth_max - 1,
                                     _fov_exit(ray, x0, y0, self.fov_radius_m), ray.maxt)
                p_prev = mi.Point3f(si.p)
                si = scene.ray_intersect(ray, active & (ray.maxt > 0.0))
                # vertex to vertex, not si.t: the ray starts off the surface
                inner_m += dr.select(si.is_valid(), dr.norm(si.p - p_prev), 0.0)
                active &= si.is_valid() & (throughput > 0)
        return tuple(out)

    # ---------------------------------------------------------------- public
    def launch(self, scene: mi.Scene, *, shot_x_m: np.ndarray, shot_y_m: np.ndarray,
               paths_per_shot: int = 128, seed: int = 0,
               offset_m: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
               ) -> "PendingReturns":
        """Start tracing and return at once where the backend allows (CUDA: the first
        integrator chunk's kernel runs while the host goes on);
        :meth:`PendingReturns.result` waits and gives what :meth:`trace` gives. Arguments as
        :meth:`trace`. Later integrator chunks (more than ``max_lanes`` lanes) are traced one
        at a time inside ``result()``, so the device holds one chunk at a time."""
        shot_x_m, shot_y_m, offset_m = _checked_shots(shot_x_m, shot_y_m, paths_per_shot,
                                                      offset_m)
        n_shots = shot_x_m.size
        lo, hi = scene_bounds(scene)
        z_start = float(hi[2]) + 1e-3 * max(float(hi[2] - lo[2]), 1.0) + 1e-2
        if not (z_start < self.altitude_m):
            raise ValueError(f"altitude_m ({self.altitude_m}) must be above the scene top "
                             f"({float(hi[2])})")
        core, slots = self._core(scene)
        per_chunk = max(1, self.max_lanes // (paths_per_shot * slots))

        def make(k: int, start: int, stop: int):
            out = core(scene, mi.Float(shot_x_m[start:stop]), mi.Float(shot_y_m[start:stop]),
                       int(paths_per_shot), dr.opaque(mi.UInt32, _mix_seed(seed, k)),
                       dr.opaque(mi.Float, z_start))
            traced = out       # held until fetched (freed in flight: host tasks behind it)
            if offset_m is not None and any(np.any(d[start:stop]) for d in offset_m):
                out = _moved(out, tuple(d[start:stop] for d in offset_m),
                             slots_per_shot=int(paths_per_shot) * slots)
            return out, traced, _kept_slots(out, int(paths_per_shot) * slots)   # evaluated

        steps = [(k, a, min(n_shots, a + per_chunk))
                 for k, a in enumerate(range(0, n_shots, per_chunk))]
        return PendingReturns(make, steps, n_shots=n_shots, paths_per_shot=int(paths_per_shot),
                              max_depth=slots)

    def _core(self, scene: mi.Scene):
        """The tracing function for ``scene`` and its output slots per photon lane."""
        if scene_medium(scene) is not None:
            raise ValueError("the scene has a participating medium (snow): trace it with the "
                             "'volpathlength' integrator (simulate() chooses it)")
        if self.max_depth == 1:
            return self._first_surface, 1
        return self._multi_bounce, self.max_depth

    def trace(self, scene: mi.Scene, *, shot_x_m: np.ndarray, shot_y_m: np.ndarray,
              paths_per_shot: int = 128, seed: int = 0,
              offset_m: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              progress=None) -> Returns:
        """Trace ``paths_per_shot`` photons for every shot.

        Args:
            scene: the Mitsuba scene (terrain in local coordinates, z up, metres).
            shot_x_m, shot_y_m: (n_shots,) footprint centres [m] in scene coordinates.
            paths_per_shot: photon paths traced per shot (Monte Carlo samples of the return).
            seed: random seed; the same seed gives the same photons.
            offset_m: optional ``(dx, dy, dz)``, three (n_shots,) arrays [m]: the shots were
                traced on a copy of the surface displaced by (-dx, -dy, -dz) (a track folded
                into a tile), and the returns are put back in place on the device: points
                move by the offset, times by -2 dz / c (as :meth:`Returns.moved`).
            progress: optional callable ``progress(n_shots_done)`` called after each chunk.

        Returns:
            :class:`~lidar_mitsuba_plugins.returns.Returns`, one entry per photon return of non-zero
            weight (at most ``n_shots * paths_per_shot * max_depth``), sorted by shot:
            ``shot`` (uint32), ``time_ns`` (float64 round-trip time [ns] from the pulse
            centre's emission), ``weight`` (float32), ``x_m``, ``y_m``, ``z_m`` (float32
            vertex position [m]), ``depth`` (uint8, 1 = first surface). The returns are
            compacted on the device (``dr.compress``): only the kept ones cross to the host
            (on the CPU backend, whose slots are host memory, numpy picks them).
        """
        return self.launch(scene, shot_x_m=shot_x_m, shot_y_m=shot_y_m,
                           paths_per_shot=paths_per_shot, seed=seed,
                           offset_m=offset_m).result(progress=progress)

    def to_string(self):
        return (f"PathLengthIntegrator[max_depth={self.max_depth}, altitude_m={self.altitude_m}, "
                f"footprint_sigma_m={self.footprint_sigma_m}, "
                f"pulse_sigma_ns={self.pulse_sigma_ns}]")


class PendingReturns:
    """A trace under way (:meth:`PathLengthIntegrator.launch`); :meth:`result` gives its
    :class:`~lidar_mitsuba_plugins.returns.Returns`. The first integrator chunk is launched at
    creation; later ones are launched and fetched one by one in ``result()``."""

    def __init__(self, make, steps, *, n_shots: int, paths_per_shot: int, max_depth: int):
        self._make, self._steps = make, steps
        self.n_shots, self.paths_per_shot, self.max_depth = n_shots, paths_per_shot, max_depth
        #: host time [s]: ``launch_s`` building and launching kernels, ``wait_s`` waiting for
        #: the device, ``fetch_s`` compacting and copying returns to numpy (bench reports the
        #: host's share of a trace from these)
        self.timings_s = {"launch_s": 0.0, "wait_s": 0.0, "fetch_s": 0.0}
        self._first = self._launch(*steps[0]) if steps else None

    def _launch(self, k: int, start: int, stop: int):
        t0 = time.perf_counter()
        out = self._make(k, start, stop)
        self.timings_s["launch_s"] += time.perf_counter() - t0
        return out

    def result(self, progress=None) -> Returns:
        """Wait for the trace and bring its non-zero returns to the host (see
        :meth:`PathLengthIntegrator.trace`). ``progress(n_shots_done)``: called per chunk."""
        if not self._steps:
            return Returns.empty(n_shots=0, paths_per_shot=self.paths_per_shot)
        parts = []
        for i, (k, start, stop) in enumerate(self._steps):
            out, traced, kept = self._first if i == 0 else self._launch(k, start, stop)
            self._first = None
            t0 = time.perf_counter()
            dr.sync_thread()
            t1 = time.perf_counter()
            parts.append((self._fetch(out, kept, stop - start), start))
            del out, traced, kept
            self.timings_s["wait_s"] += t1 - t0
            self.timings_s["fetch_s"] += time.perf_counter() - t1
            if progress is not None:
                progress(stop - start)
        # let the scene go: a live stale scene joins every later kernel's calls (a dispatch
        # loop over its instances, and a kernel of its own for each number of them)
        self._make = None
        if len(parts) == 1:
            return parts[0][0]
        out = Returns.concatenate(parts, n_shots=self.n_shots)
        out.shot = out.shot.astype(np.uint32)
        return out

    def _fetch(self, out, kept, n_shots: int) -> Returns:
        """Compact the slots of non-zero weight on the device and copy those and their shot
        (and depth) to the host; the trace's kernel wrote which slots and their shots
        (:func:`_kept_slots`) and put folded shots back in place (:func:`_moved`)."""
        t, w, x, y, z = out[:5]
        depth_of_slot = out[5] if len(out) > 5 else None      # cores that record it per slot
        keep, shot = kept
        if keep is None:                                  # the CPU backend: on the host
            return self._fetch_host(out, shot, n_shots)
        idx = dr.compress(keep)                           # synchronises; keeps slot order
        if dr.width(idx) == 0:
            return Returns.empty(n_shots=n_shots, paths_per_shot=self.paths_per_shot)
        if dr.width(idx) < dr.width(w):   # (single bounce on terrain often keeps every slot)
            shot = dr.gather(mi.UInt32, shot, idx)
            t, w = dr.gather(mi.Float64, t, idx), dr.gather(mi.Float, w, idx)
            x, y, z = (dr.gather(mi.Float, a, idx) for a in (x, y, z))
        arrays = [shot, t, w, x, y, z]
        if depth_of_slot is not None:
            arrays.append(dr.minimum(dr.gather(mi.UInt32, depth_of_slot, idx), 255))
        elif self.max_depth > 1:
            arrays.append(idx % self.max_depth + 1)
        dr.eval(*arrays)
        host = [a.numpy() for a in arrays]
        depth = (host[6].astype(np.uint8) if len(host) > 6
                 else np.ones(host[0].size, np.uint8))
        return Returns(shot=host[0], time_ns=host[1], weight=host[2], x_m=host[3],
                       y_m=host[4], z_m=host[5], depth=depth, n_shots=n_shots,
                       paths_per_shot=self.paths_per_shot)

    def _fetch_host(self, out, shot, n_shots: int) -> Returns:
        """:meth:`_fetch` on the CPU backend, where the slots are host memory: the slots of
        non-zero weight picked by numpy (``w > 0`` in float32, in slot order, as the
        device's mask and ``dr.compress``), without the compress kernel and the mask; every
        slot kept (single bounce on terrain) reads the arrays as they are."""
        host = [a.numpy() for a in (shot, *out[:5])]
        keep = host[2] > 0.0
        idx = None
        if not keep.all():
            idx = np.flatnonzero(keep)
            host = [a[idx] for a in host]
        if host[0].size == 0:
            return Returns.empty(n_shots=n_shots, paths_per_shot=self.paths_per_shot)
        if len(out) > 5:                               # cores that record it per slot
            d = out[5].numpy()
            depth = np.minimum(d if idx is None else d[idx], 255).astype(np.uint8)
        elif self.max_depth > 1:
            slot = np.arange(keep.size, dtype=np.uint32) if idx is None else idx
            depth = (slot % self.max_depth + 1).astype(np.uint8)
        else:
            depth = np.ones(host[0].size, np.uint8)
        return Returns(shot=host[0], time_ns=host[1], weight=host[2], x_m=host[3],
                       y_m=host[4], z_m=host[5], depth=depth, n_shots=n_shots,
                       paths_per_shot=self.paths_per_shot)


def _moved(out: tuple, shift: tuple[np.ndarray, np.ndarray, np.ndarray], *,
           slots_per_shot: int) -> tuple:
    """A core's ``(t, w, x, y, z, ...)`` slots put back in place as :meth:`Returns.moved`
    does, on the device and in the trace's own kernel (every slot; the fetch keeps those of
    non-zero weight): points move by the shot's ``shift`` (dx, dy, dz) [m] in float64, times
    by -2 dz / c, computed on the host per shot exactly as ``Returns.moved`` computes it, so
    both give the same bits. An offset that is the same for every shot (a DEM's corridor
    tile moves by its origin) enters as one value instead of a gather per slot."""
    t, w, x, y, z = out[:5]
    shot = None

    def same(d: np.ndarray) -> bool:
        return bool(d.size and np.all(d == d[0]))

    def per_slot(d: np.ndarray, constant: bool):
        nonlocal shot
        if constant:
            return dr.opaque(mi.Float64, float(d[0]))
        if shot is None:
            shot = _quotient(dr.arange(mi.UInt32, dr.width(w)), slots_per_shot)
        return dr.gather(mi.Float64, mi.Float64(d), shot)

    constant = [same(d) for d in shift]
    dx, dy, dz = (per_slot(d, c) for d, c in zip(shift, constant))
    if constant[2]:       # every shot's -2 dz / c the same: from the one value, as numpy would
        dt = dr.opaque(mi.Float64, 2.0 * float(shift[2][0]) / C_M_PER_NS)
    else:
        d = 2.0 * shift[2] / C_M_PER_NS
        dt = per_slot(d, same(d))
    t = t - dt
    x, y, z = (mi.Float(mi.Float64(a) + d) for a, d in ((x, dx), (y, dy), (z, dz)))
    return (t, w, x, y, z, *out[5:])


def _kept_slots(out: tuple, slots_per_shot: int) -> tuple[mi.Bool | None, mi.UInt32]:
    """Per slot of a core's output ``(t, w, ...)``: whether it returns (non-zero weight:
    the slots the fetch keeps) and its shot, evaluated with ``out`` in the trace's own
    kernel (asynchronous on CUDA). Each was a kernel of its own in the fetch, a pass over
    the weights for the mask and one over the kept slots for the shot: the same values.
    On the CPU backend the mask is ``None``: the host reads every slot there anyway and
    tests the weights itself (:meth:`PendingReturns._fetch`)."""
    w = out[1]
    shot = _quotient(dr.arange(mi.UInt32, dr.width(w)), slots_per_shot)
    keep = None if dr.backend_v(w) == dr.JitBackend.LLVM else w > 0.0
    dr.eval(*out, shot, *([] if keep is None else [keep]))
    return keep, shot


def _checked_shots(shot_x_m, shot_y_m, paths_per_shot: int, offset_m):
    """``trace``'s shot arguments checked: float32 footprint centres (n_shots,) and the
    float64 offsets (three (n_shots,) arrays, or None)."""
    shot_x_m = np.ascontiguousarray(shot_x_m, dtype=np.float32).ravel()
    shot_y_m = np.ascontiguousarray(shot_y_m, dtype=np.float32).ravel()
    if shot_x_m.shape != shot_y_m.shape:
        raise ValueError("shot_x_m and shot_y_m must have the same shape")
    if paths_per_shot < 1:
        raise ValueError(f"paths_per_shot must be >= 1 (got {paths_per_shot})")
    if offset_m is not None:
        offset_m = tuple(np.ascontiguousarray(d, np.float64).ravel() for d in offset_m)
        if len(offset_m) != 3 or any(d.shape != shot_x_m.shape for d in offset_m):
            raise ValueError("offset_m must be three (n_shots,) arrays (dx, dy, dz) [m]")
    return shot_x_m, shot_y_m, offset_m


def _fov_exit(ray: mi.Ray3f, cx: mi.Float, cy: mi.Float, radius_m: float) -> mi.Float:
    """Distance along ``ray`` at which it leaves the vertical cylinder of radius ``radius_m``
    around (cx, cy) for good (0 when it never is inside ahead; infinity when it runs
    vertically inside). Beyond it no point is in the field of view."""
    ox, oy = ray.o.x - cx, ray.o.y - cy
    a = dr.square(ray.d.x) + dr.square(ray.d.y)
    b = ox * ray.d.x + oy * ray.d.y
    c = dr.square(ox) + dr.square(oy) - radius_m * radius_m
    disc = dr.square(b) - a * c
    t_out = (dr.sqrt(dr.maximum(disc, 0.0)) - b) / dr.maximum(a, 1e-30)
    t_out = dr.select(disc >= 0.0, dr.maximum(t_out, 0.0), 0.0)
    return dr.select(a > 1e-12, t_out, dr.select(c <= 0.0, dr.inf, 0.0))


def _lone_mesh(scene: mi.Scene) -> mi.Mesh | None:
    """The scene's one shape when it is a mesh with a BSDF (a DEM's corridor tile, a
    heightfield tile), else ``None``. Every ray that hits the scene hits it, so its
    interaction and BSDF can be traced in line instead of through the registries' calls
    (a gather of the instance and of its members per lane, and a call per packet)."""
    shapes = scene.shapes()
    if len(shapes) != 1 or not shapes[0].is_mesh() or shapes[0].bsdf() is None:
        return None
    return shapes[0]


def _mesh_interaction(scene: mi.Scene, mesh: mi.Mesh, ray: mi.Ray3f) -> mi.SurfaceInteraction3f:
    """``scene.ray_intersect(ray)`` for a scene whose only shape is ``mesh``, with the mesh's
    ``compute_surface_interaction`` called in line: Mitsuba 3.9's
    ``PreliminaryIntersection::compute_surface_interaction`` and the fields of
    ``SurfaceInteraction::finalize_surface_interaction`` the integrators read (``t``, the
    shading frame, ``wi``), in its order, so the same bits (include/mitsuba/render/
    interaction.h, v3.9.1). Not as ``ray_intersect`` gives them: ``time`` and ``wavelengths``
    (not set), ``shape`` (the mesh on misses too, where ``ray_intersect`` has none)."""
    pi = scene.ray_intersect_preliminary(ray)
    active = pi.is_valid()
    si = mesh.compute_surface_interaction(ray, pi, mi.RayFlags.All, active)
    si.t = dr.select(active, si.t, dr.inf)
    si.initialize_sh_frame()
    si.wi = dr.select(active, si.to_local(-ray.d), -ray.d)
    return si


def _quotient(index: mi.UInt32, divisor: int) -> mi.UInt32:
    """``index // divisor`` for a divisor known only when the kernel runs (opaque: one kernel
    serves every paths_per_shot), without an integer division (x86 has no vector one, so it
    runs lane by lane: 5.4 ms of a 5 M-lane fetch against 1.8 ms). floor((i + 1/2) / d) in
    float64 is exact: the true value is at least 1/(2d) from an integer, the rounding error
    at most i d^-1 2^-52."""
    inv = dr.opaque(mi.Float64, 1.0 / int(divisor))
    return mi.UInt32((mi.Float64(index) + 0.5) * inv)


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
