"""Regenerate scenes/fractal_p1.8_strip.ply: a 1024 m x 40 m strip (1 m grid) of the p = 1.8,
10 m relief fractal tile (terrain seed 0) that scenes/fractal.xml loads.

    python scenes/make_fractal_ply.py
"""
import pathlib

from lidar_mitsuba import terrain
from lidar_mitsuba.surface import export_ply, heightfield_to_trimesh

hf = terrain.fractal(p=1.8, size_m=1024.0, grid_m=1.0, relief_m=10.0, seed=0)
rows = slice(512 - 20, 512 + 21)                 # y = 492 ... 532 m of the tile, 41 rows
strip = terrain.Heightfield(z_m=hf.z_m[rows, :].copy(), grid_m=1.0, periodic=False)
tm = heightfield_to_trimesh(strip)
out = pathlib.Path(__file__).with_name("fractal_p1.8_strip.ply")
export_ply(tm, out)
print(f"wrote {out}: {len(tm.vertices)} vertices, {len(tm.faces)} faces")
