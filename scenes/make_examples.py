"""Regenerate the example files that scenes/textured.xml and scenes/crevasses.xml load:

- ``albedo_stripes.png``: an 8-bit albedo map, 0.2 on its left half (u < 0.5) and 0.8 on its
  right half, for ``<texture type="bitmap" name="rho_d">`` (with ``raw`` true the 8-bit values
  are the albedo: 51/255 and 204/255).
- ``crevasses.ply``: a flat ice plain, 400 m along x by 60 m along y at z = 0, cut across the
  track by two V-shaped crevasses, 10 m wide at the top and 8 m deep, centred at
  x = -60 m and x = +60 m.

    python scenes/make_examples.py
"""
import pathlib

import numpy as np
import trimesh

import lidar_mitsuba

mi = lidar_mitsuba.ensure_renderer()      # a Mitsuba variant, for mi.Bitmap

HERE = pathlib.Path(__file__).parent

# albedo map: 64 x 8 texels, rows along v, columns along u
img = np.full((8, 64), 51, np.uint8)
img[:, 32:] = 204
mi.Bitmap(img).write(str(HERE / "albedo_stripes.png"))

# crevasses: a profile z(x) with the V's vertices, extruded along y
CREVASSES_X_M = (-60.0, 60.0)
HALF_WIDTH_M, DEPTH_M = 5.0, 8.0
xs, zs = [-200.0], [0.0]
for c in CREVASSES_X_M:
    xs += [c - HALF_WIDTH_M, c, c + HALF_WIDTH_M]
    zs += [0.0, -DEPTH_M, 0.0]
xs, zs = np.array(xs + [200.0]), np.array(zs + [0.0])
ys = np.array([-30.0, 30.0])
v = np.array([[x, y, z] for y in ys for x, z in zip(xs, zs)])
n = len(xs)
faces = []
for i in range(n - 1):                       # two triangles per strip, normals up (+z)
    a, b, c, d = i, i + 1, n + i, n + i + 1
    faces += [[a, b, d], [a, d, c]]
tm = trimesh.Trimesh(v, np.array(faces), process=False)
tm.export(str(HERE / "crevasses.ply"), file_type="ply", encoding="binary")
print(f"wrote {HERE / 'albedo_stripes.png'} and {HERE / 'crevasses.ply'} "
      f"({len(tm.vertices)} vertices, {len(tm.faces)} faces)")
