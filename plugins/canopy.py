"""Lidar path-length integrator through tree crowns as a turbid medium
(``<integrator type="canopy">``).

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``),
after ``pathlength``, on which it builds; the crowns' kernel code is ``canopy_crowns``.
"""
from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi

from lidar_mitsuba_plugins import canopy_crowns as _crowns
from lidar_mitsuba_plugins import canopy_table
from lidar_mitsuba_plugins.constants import C_M_PER_NS, REFERENCE_ALBEDO

_pathlength = sys.modules[f"lidar_mitsuba_plugins._{mi.variant()}_pathlength"]
crown_chord = _crowns.crown_chord
_fov_exit = _pathlength._fov_exit
#: leaf normals per photon tried before giving up (acceptance >= 0.21 per try: 0.79^96 ~ 1e-10)
NORMAL_TRIES = 96


class CanopyIntegrator(_pathlength.PathLengthIntegrator):
    r"""
    Lidar path-length integrator through turbid tree crowns (:monosp:`canopy`)
    ---------------------------------------------------------------------------

    Tree crowns (cones, ellipsoids or cylinders, from a canopy table:
    ``lidar_mitsuba_plugins.canopy_table``) filled with randomly placed leaves: a turbid
    medium of extinction :math:`\sigma_t(\Omega) = G(\Omega)\,\Omega_c\,u_L` (Ross's G of the
    leaf angle distribution, the clumping index, the leaf area density), over the scene's
    surfaces (the ground, with their own BSDFs). Crowns may overlap (their extinctions add).
    The crowns are intersected in the kernel (no Mitsuba shapes); the scene supplies the ground.

    .. pluginparameters::

     * - filename
       - |string|
       - A canopy table (``canopy_table.save``), or set one with ``set_table(table)``.
     * - mode
       - |string|
       - ``turbid`` (default): Monte Carlo through the crowns, free paths sampled per
         crown, leaves scattering bi-Lambertian light, up to ``max_depth`` vertices.
         ``gap``: the gap-probability layer: per photon its vertical line's gap
         probability, two records (the canopy's return, at a height drawn from the
         collision density, and the ground's), single scattering, no sampling of the path.
     * - hot_spot
       - |bool|
       - The way back is the way in (default true): the first vertex of a path returns
         through the gaps it came down through (transmittance 1 given the way in). False
         samples the way back independently (Beer-Lambert on the way up): wrong for leaves,
         kept to show by how much.
     * - max_depth
       - |int|
       - ``turbid``: vertices per path, leaf scatterings and surface hits (default 3).
     * - (others)
       - as ``pathlength``: ``altitude_m``, ``footprint_sigma_m``, ``pulse_sigma_ns``,
         ``fov_radius_m``, ``max_lanes``.

    **The hot spot.** The lidar is monostatic: the light scattered straight back leaves along
    the line it came in on, to within the telescope's aperture over the orbit (0.8 m at
    496 km: 1.6 microradians, 0.05 mm across 30 m of canopy), far less than a leaf. The
    leaves that let the pulse through therefore let its echo out: the gap probabilities of
    the ways in and out are one (Kuusk 1985, "The hot spot effect of a uniform vegetative
    cover", Sov. J. Remote Sens. 3, 645-658: the joint gap probability of two paths
    separated by less than the leaf size is that of one path). The return of a path's
    first vertex (a leaf or the ground) carries no transmittance on its way up. Later
    vertices' returns leave along other lines: Beer-Lambert through the crowns they cross,
    and a shadow ray against the scene.

    **A leaf collision** (``turbid``): the leaf's normal is sampled from
    :math:`g_L(\Omega_L)|\Omega\cdot\Omega_L|/G(\Omega)` (its inclination by rejection from
    the leaf angle distribution), the return toward the receiver is that leaf's
    :math:`\pi f_L\cos/0.9` (:math:`\rho` on its lit side, :math:`\tau` through it; an
    unbiased estimate of the area scattering phase function), and the path goes on
    reflected (probability :math:`\rho/(\rho+\tau)`) or transmitted, cosine-distributed
    about the leaf, its throughput times :math:`\rho + \tau`. Free paths are sampled per
    crown along the ray (the first collision of independent media is the least of their
    own), so overlapping crowns need no sorting.

    **The gap layer** (``gap``): along each photon's vertical line the optical depth
    :math:`\tau = \sum_k G(1)\,\Omega_c\,u_L\,\ell_k` (the chords :math:`\ell_k` of the
    crowns it crosses), the ground's return times :math:`P = e^{-\tau}` (hot spot;
    :math:`P^2` without), and the canopy's, :math:`(1 - P)\,\pi\Gamma_b/(G\,0.9)`
    (:math:`(1 - P^2)/2` times it without), at the depth where the optical depth reaches
    :math:`-\ln(1 - u(1 - P))` (the piecewise-linear optical depth walked from chord end to
    chord end, the chords in local memory). Slot 1 the canopy, slot 2 the ground; both
    report depth 1 (each is a first vertex).

    Crowns are found through a uniform grid of 1 m cells, each listing the crowns over it:
    a vertical line looks in one cell, an oblique leg walks the cells it crosses (a 2-D DDA)
    until the first collision found ends before the next cell. A leg after the first ends
    where it leaves the field of view's cylinder (a photon scattered out of it is dropped:
    nothing it does later is seen, but for light scattered back into the field of view,
    left out).

    **A stand over a DEM's corridor tiles** (``set_stand`` once, ``set_tile`` per tile): one
    grid of the periodic stand's square and the images near its edges (within the field of
    view's diameter: as far as any leg reaches from where it starts), the crowns' heights
    above their ground; each leg is wrapped into the square where it starts, and a crown
    stands on the tile's ground under its image (the tile's ``ground_z_m``), so no tile
    gathers or bins crowns of its own.

    .. tabs::

        .. code-tab:: xml

            <integrator type="canopy">
                <string name="filename" value="stand.npz"/>
                <string name="mode" value="turbid"/>
            </integrator>

        .. code-tab:: python

            {'type': 'canopy', 'filename': 'stand.npz', 'mode': 'turbid'}
    """

    def __init__(self, props: mi.Properties):
        if "max_depth" not in props:
            props["max_depth"] = 3
        filename = props.get("filename", "")
        self.mode = str(props.get("mode", "turbid"))
        self.hot_spot = bool(props.get("hot_spot", True))
        super().__init__(props)
        if self.mode not in ("turbid", "gap"):
            raise ValueError(f"canopy: mode must be 'turbid' or 'gap' (got {self.mode!r})")
        self._table = None
        if filename:
            self.set_table(canopy_table.load(filename))

    def set_table(self, table: dict) -> None:
        """Use a canopy table (module ``canopy_table``): its crowns, foliage and grids."""
        t = canopy_table.check(table)
        self._table = _crowns.tables(t, _crowns.grid_of(t), tiled=False)
        self._table["top"] = dr.opaque(mi.Float, float(t["zt"].max(initial=-1e30)) + 1e-2)

    def set_stand(self, crowns: dict) -> None:
        """Use a stand's crowns over a DEM's corridor tiles (``lidar_mitsuba.vegetation.
        turbid.stand_crowns``), uploaded once with their grid; each tile then hands the
        ground under them (:meth:`set_tile`)."""
        self._table = _crowns.stand_tables(crowns)

    def set_tile(self, tile: dict) -> None:
        """A corridor tile's ground under the stand's crowns (``lidar_mitsuba.vegetation.
        turbid.tile_crowns``), as opaque values: every tile reuses the kernels."""
        if self._table is None or not self._table["tiled"]:
            raise ValueError("canopy: set_tile needs a stand (set_stand)")
        (sx, sy), (bx, by), (mx, my) = tile["shift_m"], tile["image0"], tile["images"]
        self._table["tile"] = (
            dr.opaque(mi.Float, sx), dr.opaque(mi.Float, sy), dr.opaque(mi.Int32, bx),
            dr.opaque(mi.Int32, by), dr.opaque(mi.Int32, mx), dr.opaque(mi.Int32, my),
            dr.opaque(mi.UInt32, tile["trees"]), mi.Float(tile["ground_z_m"]))
        self._table["top"] = dr.opaque(mi.Float, float(tile["top_m"]))

    def _emit(self, sx, sy, paths_per_shot, seed, z_start):
        """``pathlength``'s photons, starting above the crowns as well as the scene (the
        crowns are not shapes of the scene: its bounds do not hold them)."""
        top = dr.maximum(z_start, self._table["top"])
        return super()._emit(sx, sy, paths_per_shot, seed, top)

    def _core(self, scene: mi.Scene):
        if self._table is None:
            raise ValueError("canopy: no table (give filename or call set_table)")
        if self._table["tiled"] and self._table["tile"] is None:
            raise ValueError("canopy: a stand without a tile (call set_tile)")
        if self.mode == "gap":
            return self._gap, 2
        return self._turbid, self.max_depth

    # ------------------------------------------------------------- crowns (traced)
    def _sigma(self, d: mi.Vector3f) -> mi.Float:
        """Extinction [1/m] along ``d``: G(|d_z|) Omega u_L, linear in the table's nodes."""
        tab = self._table
        x = dr.abs(d.z) * (tab["n_g"] - 1)
        i = dr.minimum(mi.UInt32(x), tab["n_g"] - 2)
        f = x - mi.Float(i)
        return dr.lerp(dr.gather(mi.Float, tab["sigma_g"], i),
                       dr.gather(mi.Float, tab["sigma_g"], i + 1), f)

    def _cells(self, grid, x: mi.Float, y: mi.Float, active: mi.Bool):
        """The range ``[start, end)`` of ``trees`` in the cell of ``grid`` holding (x, y)."""
        x0, y0, nx, ny, cell, off, _ = grid
        ix = mi.Int32(dr.floor((x - x0) / cell))
        iy = mi.Int32(dr.floor((y - y0) / cell))
        ok = active & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        c = mi.UInt32(dr.select(ok, iy * nx + ix, 0))
        start = dr.gather(mi.UInt32, off, c, ok)
        end = dr.gather(mi.UInt32, off, c + 1, ok)
        return start, dr.select(ok, end, start)

    def _chord(self, k: mi.UInt32, o: mi.Point3f, d: mi.Vector3f, active: mi.Bool,
               image=None):
        """Entry and exit distances ``(t0, t1)`` of the ray ``o + t d`` through crown ``k``
        (``t0 >= t1``: it misses); ``image``: see :func:`_tile_chord`."""
        tab = self._table
        cx, cy, zb, zt, r = (dr.gather(mi.Float, a, k, active) for a in tab["crowns"])
        if image is None:
            return crown_chord(tab["shape"], o, d, cx, cy, zb, zt, r)
        return _crowns.tile_chord(tab, k, o, d, active, image, (cx, cy, zb, zt, r))

    @dr.syntax
    def _first_collision(self, o, d, t_max, seed, active):
        """Distance to the first leaf along ``o + t d`` before ``t_max`` (inf if none): the
        least of each crown's own exponential free path (independent media), the crowns
        visited cell by cell along the ray (a 2-D DDA over the grid), stopping at the first
        cell that ends beyond a collision found. A crown listed in several cells draws the
        same free path in each (its uniform variate hashes ``seed`` and its index)."""
        x0, y0, nx, ny, cell, off, trees = self._table["line"]
        sigma = dr.maximum(self._sigma(d), 1e-30)
        ox, oy, image = _crowns.tile_local(self._table, o.x, o.y)
        o = mi.Point3f(ox, oy, o.z)
        fx, fy = (o.x - x0) / cell, (o.y - y0) / cell
        ix, iy = mi.Int32(dr.floor(fx)), mi.Int32(dr.floor(fy))
        step_x = dr.select(d.x > 0.0, 1, -1)
        step_y = dr.select(d.y > 0.0, 1, -1)
        inv_x = dr.select(dr.abs(d.x) > 1e-9, cell / dr.abs(d.x), dr.inf)
        inv_y = dr.select(dr.abs(d.y) > 1e-9, cell / dr.abs(d.y), dr.inf)
        next_x = dr.select(d.x > 0.0, dr.floor(fx) + 1.0 - fx, fx - dr.floor(fx)) * inv_x
        next_y = dr.select(d.y > 0.0, dr.floor(fy) + 1.0 - fy, fy - dr.floor(fy)) * inv_y
        t_c = mi.Float(dr.inf)
        go = mi.Bool(active)
        visits = mi.UInt32(0)
        while go:
            inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
            c = mi.UInt32(dr.select(inside, iy * nx + ix, 0))
            k = dr.gather(mi.UInt32, off, c, go & inside)
            end = dr.select(inside, dr.gather(mi.UInt32, off, c + 1, go & inside), k)
            while go & (k < end):
                tree = dr.gather(mi.UInt32, trees, k, go)
                t0, t1 = self._chord(tree, o, d, go, image)
                t0 = dr.maximum(t0, 0.0)
                t1 = dr.minimum(t1, t_max)
                u = mi.sample_tea_float32(seed, tree)
                t = t0 - dr.log(dr.maximum(1.0 - u, 1e-30)) / sigma
                t_c = dr.select(go & (t0 < t1) & (t < t1), dr.minimum(t_c, t), t_c)
                k += 1
            t_exit = dr.minimum(next_x, next_y)
            along_x = next_x <= next_y
            ix += dr.select(along_x, step_x, 0)
            iy += dr.select(along_x, 0, step_y)
            next_x += dr.select(along_x, inv_x, 0.0)
            next_y += dr.select(along_x, 0.0, inv_y)
            visits += 1
            # on while the next cell starts before the collision found and the ray's end,
            # and lies on the grid
            go &= ((t_exit < t_c) & (t_exit < t_max) & (ix >= 0) & (ix < nx) & (iy >= 0)
                   & (iy < ny) & (mi.Int32(visits) < 4 * (nx + ny)))
        return t_c

    @dr.syntax
    def _depth(self, grid, o, d, t_max, lane_x, lane_y, active):
        """Optical depth of the crowns along ``o + t d``, ``0 <= t <= t_max`` (the crowns
        of the cell of (``lane_x``, ``lane_y``))."""
        lx, ly, image = _crowns.tile_local(self._table, lane_x, lane_y)
        o = mi.Point3f(o.x + (lx - lane_x), o.y + (ly - lane_y), o.z)
        start, end = self._cells(grid, lx, ly, active)
        length = mi.Float(0.0)
        k = mi.UInt32(start)
        while active & (k < end):
            tree = dr.gather(mi.UInt32, grid[6], k)
            t0, t1 = self._chord(tree, o, d, active, image)
            length += dr.maximum(dr.minimum(t1, t_max) - dr.maximum(t0, 0.0), 0.0)
            k += 1
        return length * self._sigma(d)

    @dr.syntax
    def _sample_normal(self, d: mi.Vector3f, sampler, active: mi.Bool) -> mi.Vector3f:
        """A leaf normal (upper hemisphere) drawn from g_L |d . n| by rejection: the
        inclination uniform, accepted with f(theta_L) / max f times |d . n|."""
        n = mi.Vector3f(0.0, 0.0, 1.0)
        todo = mi.Bool(active)
        i = mi.UInt32(0)
        code = self._table["leaf_angle"]
        while todo & (i < NORMAL_TRIES):
            theta = sampler.next_1d(todo) * (0.5 * dr.pi)
            sin_p, cos_p = dr.sincos(dr.two_pi * sampler.next_1d(todo))
            sin_t, cos_t = dr.sincos(theta)
            cand = mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t)
            c2 = dr.cos(2.0 * theta)
            rel = [sin_t, 0.5 * (1.0 + c2), 0.5 * (1.0 - c2), mi.Float(1.0)][code]
            ok = todo & (sampler.next_1d(todo) < rel * dr.abs(dr.dot(d, cand)))
            n = dr.select(ok, cand, n)
            todo &= ~ok
            i += 1
        return n

    def _leaf(self, d: mi.Vector3f, wo: mi.Vector3f, sampler, active: mi.Bool,
              way_on: bool = True):
        """A leaf collision of a photon travelling along ``d``: ``(value, d_new)``, the
        return toward ``wo`` (pi f_L cos / 0.9 of a leaf drawn by :meth:`_sample_normal`:
        rho on its lit side, tau through it) and the next direction (reflected with
        probability rho / (rho + tau), else transmitted; cosine-distributed about the
        leaf). The path's throughput is to be multiplied by rho + tau."""
        tab = self._table
        n_leaf = self._sample_normal(d, sampler, active)
        dn, wn = dr.dot(d, n_leaf), dr.dot(wo, n_leaf)
        value = dr.select(dn * wn < 0.0, tab["rho"], tab["tau"]) * dr.abs(wn) / REFERENCE_ALBEDO
        if not way_on:                   # (the path's last vertex: its next direction unused)
            return value, d
        reflect = sampler.next_1d(active) * tab["omega"] < tab["rho"]
        side = dr.select(dn < 0.0, 1.0, -1.0) * dr.select(reflect, 1.0, -1.0)
        local = mi.warp.square_to_cosine_hemisphere(sampler.next_2d(active))
        return value, mi.Frame3f(n_leaf * side).to_world(local)

    # ------------------------------------------------------------- the two kernels
    def _gap(self, scene, sx, sy, paths_per_shot, seed, z_start):
        """Two slots per photon (canopy, ground): time [ns], weight, x, y, z, depth."""
        return _gap_kernel(self, scene, sx, sy, paths_per_shot, seed, z_start)

    def _turbid(self, scene, sx, sy, paths_per_shot, seed, z_start):
        """``max_depth`` slots per photon: time [ns], weight, vertex x, y, z."""
        return _walk(self, scene, sx, sy, paths_per_shot, seed, z_start)

    def to_string(self):
        n = 0 if self._table is None else self._table["n"]
        return (f"CanopyIntegrator[mode={self.mode}, hot_spot={self.hot_spot}, crowns={n}, "
                f"max_depth={self.max_depth}]")


def _gap_kernel(integ, scene, sx, sy, paths_per_shot, seed, z_start):
    """The gap layer (see the class): two slots per photon."""
    n = dr.width(sx) * paths_per_shot
    x0, y0, sampler, ray, t_emit_ns, si, leg_m, wo, seen = integ._first_hit(
        scene, sx, sy, paths_per_shot, seed, z_start)
    t_g = dr.select(si.is_valid(), si.t, 0.0)
    two_way = integ.hot_spot
    u = sampler.next_1d(seen)
    t_c, p_gap = _line(integ, ray, t_g, u, seen)
    w_ground = integ._return_weight(si, wo, seen) * (p_gap if two_way else p_gap * p_gap)
    q = (1.0 - p_gap) if two_way else 0.5 * (1.0 - p_gap * p_gap)
    p_c = ray.o + ray.d * t_c
    leg_c = integ._leg_m(p_c, mi.Float64(x0), mi.Float64(y0))
    w_canopy = dr.select(seen, q * integ._table["leaf_nadir"], 0.0)
    t_ground = mi.Float64(t_emit_ns) + (leg_m + leg_m) / C_M_PER_NS
    t_canopy = mi.Float64(t_emit_ns) + (leg_c + leg_c) / C_M_PER_NS
    lane = dr.arange(mi.UInt32, n)
    out = [dr.zeros(mi.Float64 if k == 0 else mi.Float, 2 * n) for k in range(5)]
    for slot, vals in ((2 * lane, (t_canopy, w_canopy, p_c.x, p_c.y, p_c.z)),
                       (2 * lane + 1, (t_ground, w_ground, si.p.x, si.p.y, si.p.z))):
        for target, v in zip(out, vals):
            dr.scatter(target, v, slot)
    return (*out, dr.full(mi.UInt32, 1, 2 * n))

@dr.syntax
def _line(integ, ray, t_g, u, active):
    """The vertical line of ``ray`` down to the ground at ``t_g``: ``(t_c, P_gap)``, the
    gap probability and the distance of a canopy return drawn from the collision
    density (``sigma e^-tau``, or ``sigma e^-2 tau`` without the hot spot) with the
    uniform ``u``: where the optical depth reaches ``tau* = -ln(1 - u (1 - P))`` (or
    half of ``-ln(1 - u (1 - P^2))``). The crowns' chords are kept in local memory; the
    optical depth is piecewise linear between their ends, walked end by end (exact)."""
    x0, y0, nx, ny, cell, off, trees = integ._table["line"]
    sigma = integ._table["sigma_nadir"]
    ox, oy, image = _crowns.tile_local(integ._table, ray.o.x, ray.o.y)
    o = mi.Point3f(ox, oy, ray.o.z)
    start, end = integ._cells(integ._table["line"], ox, oy, active)
    a_buf = dr.alloc_local(mi.Float, integ._table["max_per_cell"], mi.Float(0.0))
    b_buf = dr.alloc_local(mi.Float, integ._table["max_per_cell"], mi.Float(0.0))
    length = mi.Float(0.0)
    k = mi.UInt32(start)
    while active & (k < end):
        t0, t1 = integ._chord(dr.gather(mi.UInt32, trees, k, active), o, ray.d, active,
                              image)
        t0 = dr.maximum(t0, 0.0)
        t1 = dr.minimum(t1, t_g)
        keep = active & (t1 > t0)
        # slot k - start (a crown the line misses: the empty chord [0, 0]); slots counted
        # up only for the crowns hit put chords in the wrong slots (drjit 1.5, LLVM: a
        # conditionally incremented index into local memory, in a loop)
        a_buf[k - start] = dr.select(keep, t0, 0.0)
        b_buf[k - start] = dr.select(keep, t1, 0.0)
        length += dr.select(keep, t1 - t0, 0.0)
        k += 1
    count = end - start
    p_gap = dr.exp(-sigma * length)
    two_way = integ.hot_spot
    top = (1.0 - p_gap) if two_way else (1.0 - p_gap * p_gap)
    tau_star = -dr.log(dr.maximum(1.0 - u * top, 1e-30)) * (1.0 if two_way else 0.5)
    t = mi.Float(0.0)
    acc = mi.Float(0.0)                  # the optical depth down to t
    todo = active & (length > 0.0)
    step = mi.UInt32(0)
    while todo & (step < 2 * count + 1):
        inside = mi.UInt32(0)
        nxt = mi.Float(dr.inf)           # the next chord end beyond t
        j = mi.UInt32(0)
        while todo & (j < count):
            a, b = a_buf[j], b_buf[j]
            inside += dr.select((a <= t) & (t < b), 1, 0)
            nxt = dr.minimum(nxt, dr.select(a > t, a, dr.select(b > t, b, dr.inf)))
            j += 1
        slope = sigma * mi.Float(inside)
        gain = slope * (nxt - t)
        here = (acc + gain >= tau_star) & (inside > 0)
        t = dr.select(here, t + (tau_star - acc) / dr.maximum(slope, 1e-30), nxt)
        acc += dr.select(here, 0.0, gain)
        todo &= ~here & dr.isfinite(nxt)
        step += 1
    return t, p_gap


@dr.syntax
def _walk(integ, scene, sx, sy, paths_per_shot, seed, z_start):
    """The turbid kernel: a symbolic loop over each path's vertices (see the class)."""
    tab = integ._table
    n, depth_max = dr.width(sx) * paths_per_shot, integ.max_depth
    lane = dr.arange(mi.UInt32, n)
    x0, y0, sampler, ray, t_emit_ns = integ._emit(sx, sy, paths_per_shot, seed, z_start)
    sx64, sy64 = mi.Float64(x0), mi.Float64(y0)
    out = [dr.zeros(mi.Float64 if k == 0 else mi.Float, n * depth_max) for k in range(5)]
    fov2 = integ.fov_radius_m ** 2
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    line = tab["line"]
    omega = tab["omega"]
    hot = integ.hot_spot
    throughput = mi.Float(1.0)
    down_m = mi.Float64(0.0)
    inner_m = mi.Float64(0.0)
    depth = mi.UInt32(0)
    active = mi.Bool(True)
    while active & (depth < depth_max):
        first = depth == 0
        si = scene.ray_intersect(ray, active)
        t_g = dr.select(si.is_valid(), si.t, dr.inf)
        # the crowns up to the ground or, after the first leg, to the field of view's edge
        # (beyond it nothing returns: a photon leaving it is dropped)
        t_fov = _fov_exit(ray, x0, y0, integ.fov_radius_m)
        t_max = dr.select(first, t_g, dr.minimum(t_g, t_fov))
        seg_seed = mi.UInt32(sampler.next_1d(active) * 4294967040.0)
        t_c = integ._first_collision(ray.o, ray.d, t_max, seg_seed, active)
        scatter = active & (t_c < t_max)
        surface = active & ~scatter & si.is_valid() & (t_g <= t_max)
        vertex = scatter | surface
        p = dr.select(scatter, ray.o + ray.d * t_c, si.p)
        down_m = dr.select(vertex & first, integ._leg_m(p, sx64, sy64), down_m)
        inner_m += mi.Float64(dr.select(vertex & ~first, dr.norm(p - ray.o), 0.0))

        # -- the return toward the receiver
        up_m = integ._leg_m(p, sx64, sy64)
        wo = integ._to_receiver(p, sx64, sy64, up_m)
        seen = vertex & (dr.square(p.x - x0) + dr.square(p.y - y0) <= fov2)
        leaf_val, d_leaf = integ._leaf(ray.d, wo, sampler, scatter, way_on=depth_max > 1)
        value = dr.select(scatter, leaf_val, integ._return_weight(si, wo, surface & seen))
        # the way up: through the same gaps for the first vertex (hot spot), else
        # Beer-Lambert through the crowns and a shadow ray against the scene
        n_off = dr.select(scatter, mi.Vector3f(0.0), si.n)
        up = _pathlength_spawn(p, n_off, wo)
        blocked, trans = mi.Bool(False), mi.Float(1.0)
        if depth_max > 1 or not hot:     # (Python: one vertex seen through its own gaps)
            blocked = scene.ray_test(up, seen & ~first)
            # (wo is within microradians of the vertical: the crowns over p's cell are those
            # it crosses, to within a millimetre of their edges)
            tau_up = integ._depth(line, up.o, wo, dr.inf, p.x, p.y, seen & (~first | (not hot)))
            trans = dr.select(first & hot, 1.0, dr.exp(-tau_up))
        w = dr.select(seen & ~blocked, throughput * value * trans, 0.0)
        t_ns = mi.Float64(t_emit_ns) + (down_m + inner_m + up_m) / C_M_PER_NS
        slot = lane * depth_max + depth
        for target, val in zip(out, (t_ns, w, p.x, p.y, p.z)):
            dr.scatter(target, val, slot, vertex)

        # -- the next direction: the leaf reflects or transmits (Lambertian), the ground
        # samples its BSDF
        if depth_max > 1:                # (Python: after the last vertex, no way on)
            bs, bsdf_w = si.bsdf().sample(ctx, si, sampler.next_1d(surface),
                                          sampler.next_2d(surface), surface)
            d_new = dr.select(scatter, d_leaf, si.to_world(bs.wo))
            throughput *= dr.select(scatter, omega, bsdf_w[0])
            ray = dr.select(vertex, _pathlength_spawn(p, n_off, d_new), ray)
        depth += 1
        active &= vertex & (throughput > 0.0)
    return tuple(out)


def _pathlength_spawn(p: mi.Point3f, n: mi.Vector3f, d: mi.Vector3f) -> mi.Ray3f:
    """A ray from ``p`` toward ``d``, lifted off a surface of normal ``n`` (zero in the
    crowns: no lift) by (1 + max|p|) * 2^-20, as ``pathlength``'s spawn."""
    side = dr.select(dr.dot(n, d) >= 0.0, 1.0, -1.0)
    eps = (1.0 + dr.max(dr.abs(p))) * (2.0 ** -20)
    return mi.Ray3f(p + n * (side * eps), d)


mi.register_integrator("canopy", lambda props: CanopyIntegrator(props))
