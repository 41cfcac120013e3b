"""Lidar path-length integrator with a tabulated subsurface kernel
(``<integrator type="snowkernel">``).

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``),
after ``pathlength``, on which it builds.
"""
from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi
import numpy as np

from lidar_mitsuba_plugins import kernel_table
from lidar_mitsuba_plugins.constants import C_M_PER_NS
from lidar_mitsuba_plugins.kernel_table import THETA_STEP_DEG, U_POWER

_pathlength = sys.modules[f"lidar_mitsuba_plugins._{mi.variant()}_pathlength"]


class SnowKernelIntegrator(_pathlength.PathLengthIntegrator):
    r"""
    Lidar path-length integrator with a subsurface kernel (:monosp:`snowkernel`)
    ----------------------------------------------------------------------------

    The ``pathlength`` integrator for a snowpack described by a *kernel*: for light arriving
    at incidence angle :math:`\theta` on a facet of a homogeneous (or layered) snowpack, the
    return weight per incident photon :math:`W(\theta)` and the distribution of the extra
    optical path :math:`L` the returned light spends inside the snow (the group index
    included), tabulated once from the full random walk (``volpathlength``) on a plane.
    Each photon that meets the snow's boundary (a ``null`` BSDF) returns at once from its
    entry point with weight :math:`W(\theta)` and a delay :math:`L / c` drawn from the
    table: the cost of a surface hit. An opaque first surface returns as in ``pathlength``.

    At nadir the incidence angle on a facet is its tilt, and the light returns toward the
    receiver along the way it came, so one angle describes the geometry. What the kernel
    leaves out of the walk: the returned light's sideways spread (millimetres to centimetres,
    the table's ``lateral_p99_m``; the record sits at the entry point) and the per-photon
    fluctuation of the return weight (every photon on a facet carries the mean
    :math:`W(\theta)`; the detector sees the same expected photon count and delay
    distribution). Both the walk and the kernel treat the entry facet as a plane.

    .. pluginparameters::

     * - filename
       - |string|
       - A table written by ``lidar_mitsuba_plugins.kernel_table.save`` (``.npz``:
         ``weight`` (J,), ``extra_path_m`` (J, M), nodes every 5 deg of incidence from 0);
         or set one with ``set_table(weight=..., extra_path_m=...)``.
     * - (others)
       - as ``pathlength``: ``altitude_m``, ``footprint_sigma_m``, ``pulse_sigma_ns``,
         ``fov_radius_m``, ``max_lanes`` (``max_depth`` is 1: one record per photon).

    Table lookup: the facet's angle :math:`\theta` falls between nodes :math:`j` and
    :math:`j + 1` (fraction :math:`f`); the weight interpolates linearly, and the delay is
    drawn from node :math:`j + 1` with probability :math:`f`, else from node :math:`j` (the
    mixture of the two distributions), by linear interpolation of the quantile function.
    Facets steeper than the last node use the last node.

    .. tabs::

        .. code-tab:: xml

            <integrator type="snowkernel">
                <string name="filename" value="snow_100um_350.npz"/>
            </integrator>

        .. code-tab:: python

            {'type': 'snowkernel', 'filename': 'snow_100um_350.npz'}
    """

    def __init__(self, props: mi.Properties):
        filename = props.get("filename", "")
        if "max_depth" in props and int(props["max_depth"]) != 1:
            raise ValueError("snowkernel: max_depth must be 1 (one record per photon)")
        super().__init__(props)
        self.max_depth = 1
        self._table = None
        if filename:
            t = kernel_table.load(filename)
            self.set_table(weight=t["weight"], extra_path_m=t["extra_path_m"])

    def set_table(self, *, weight: np.ndarray, extra_path_m: np.ndarray) -> None:
        """Use a kernel table: ``weight`` (J,) return weight per incident photon at incidence
        angles ``0, 5, ... 5 (J - 1)`` deg, ``extra_path_m`` (J, M) the extra optical path
        [m] at the quantiles ``u_k = 1 - (1 - k / (M - 1))^4`` of its weighted
        distribution. The table's values enter the kernel as data (a new table reuses the
        compiled trace); its shape (J, M) as constants."""
        w = np.ascontiguousarray(weight, np.float32).ravel()
        q = np.ascontiguousarray(extra_path_m, np.float32)
        if q.ndim != 2 or q.shape[0] != w.size or q.shape[1] < 2 or w.size < 1:
            raise ValueError("snowkernel: weight (J,) and extra_path_m (J, M) do not match "
                             f"(got {w.shape} and {q.shape})")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0) and np.all(np.isfinite(q))
                and np.all(np.diff(q, axis=1) >= 0)):
            raise ValueError("snowkernel: the table needs finite weights >= 0 and "
                             "non-decreasing quantiles")
        self._table = (mi.Float(w), mi.Float(q.ravel()), int(w.size), int(q.shape[1]))

    def _core(self, scene: mi.Scene):
        if self._table is None:
            raise ValueError("snowkernel: no table (give filename or call set_table)")
        return self._kernel, 1

    def _kernel(self, scene: mi.Scene, sx: mi.Float, sy: mi.Float, paths_per_shot: int,
                seed: mi.UInt32, z_start: mi.Float):
        """Per photon: the first surface; an opaque one returns as in ``pathlength``, the
        snow's boundary returns the kernel's weight and delay. Returns Dr.Jit arrays of
        length ``n`` (one slot per photon): time [ns] (float64), weight (0 where nothing
        returns), entry point x, y, z [m]."""
        weight, quantiles, n_nodes, n_q = self._table
        x0, y0, sampler, ray, t_emit_ns, si, leg_m, wo, in_fov = self._first_hit(
            scene, sx, sy, paths_per_shot, seed, z_start)
        null = si.is_valid() & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)
        opaque = in_fov & ~null
        snow = in_fov & null
        w_surface = self._return_weight(si, wo, opaque)
        # the facet's incidence angle in node units, and the two nodes around it
        theta = dr.acos(dr.clip(dr.abs(si.n.z), 0.0, 1.0)) * (180.0 / dr.pi / THETA_STEP_DEG)
        theta = dr.minimum(theta, n_nodes - 1.0)
        j = dr.minimum(mi.UInt32(theta), n_nodes - 1)
        j1 = dr.minimum(j + 1, n_nodes - 1)
        f = theta - mi.Float(j)
        w_snow = dr.lerp(dr.gather(mi.Float, weight, j, snow),
                         dr.gather(mi.Float, weight, j1, snow), f)
        node = dr.select(sampler.next_1d(snow) < f, j1, j)
        # the extra path: the node's quantile function at u, linear between its nodes
        u = sampler.next_1d(snow)
        k = (n_q - 1.0) * (1.0 - dr.power(1.0 - u, 1.0 / U_POWER))
        k0 = dr.minimum(mi.UInt32(k), n_q - 2)
        frac = k - mi.Float(k0)
        base = node * n_q + k0
        extra_m = dr.lerp(dr.gather(mi.Float, quantiles, base, snow),
                          dr.gather(mi.Float, quantiles, base + 1, snow), frac)
        w = dr.select(snow, w_snow, w_surface)
        t_ns = (mi.Float64(t_emit_ns) + (leg_m + leg_m) / C_M_PER_NS
                + mi.Float64(dr.select(snow, extra_m, 0.0)) / C_M_PER_NS)
        return t_ns, w, si.p.x, si.p.y, si.p.z

    def to_string(self):
        n = 0 if self._table is None else self._table[2]
        return (f"SnowKernelIntegrator[nodes={n}, altitude_m={self.altitude_m}, "
                f"footprint_sigma_m={self.footprint_sigma_m}]")


mi.register_integrator("snowkernel", lambda props: SnowKernelIntegrator(props))
