"""Shots/s of ``simulate`` at two commits, interleaved in one run:
``python scripts/ab_speed.py OLD_REV [NEW_REV|.] [--shots N] [--repeats R] [--out FILE.json]``.

Speed-ups are claimed against an earlier commit (issue 14: "2x today's shots/s"), and this VM's
load swings by tens of per cent within a minute, so the two versions must run alternately:
each repeat runs every case once for each version, each in a fresh process (kernel cache
warm: a first, discarded call compiles), and the table gives medians and the ratio of medians.
A revision is checked out with ``git worktree`` under the system temp folder and imported
ahead of the installed package through ``PYTHONPATH``; ``.`` is this working tree.

Cases: strong beam over the p = 1.8 fractal (the bench's end-to-end track), max_depth auto
(two bounces there) and 1; the whole call, and the trace-and-detect loop alone
(``timings_s``: trace_s + detect_s).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
CASES = (("strong", "auto"), ("strong", 1))

CHILD = r"""
import json, sys, time
import lidar_mitsuba
try:                                    # the layout since issue 33
    from lidar_mitsuba.run import simulate, SurfaceSpec
except ImportError:                     # an older commit's
    from lidar_mitsuba.simulate import simulate, SurfaceSpec
from lidar_mitsuba.instrument import Instrument
beam, depth, shots = sys.argv[1], sys.argv[2], int(sys.argv[3])
depth = depth if depth == "auto" else int(depth)
def run():
    return simulate(instrument=Instrument(beam=beam), shots=shots, seed=1, progress=False,
                    surface=SurfaceSpec(kind="fractal", p=1.8), max_depth=depth)
run()                                   # compile (or read the kernel cache) and warm up
t = time.perf_counter()
res = run()
sec = time.perf_counter() - t
st = res.timings_s
print(json.dumps({"seconds": sec, "loop_s": st["trace_s"] + st["detect_s"],
                  "photons": int(res.detections.time_ns.size)}))
"""


def checkout(rev: str) -> pathlib.Path:
    """The source tree of ``rev`` (``.``: this working tree)."""
    if rev == ".":
        return ROOT
    sha = subprocess.check_output(["git", "-C", str(ROOT), "rev-parse", "--short", rev],
                                  text=True).strip()
    path = pathlib.Path(tempfile.gettempdir()) / f"lidar_mitsuba_ab_{sha}"
    if not path.exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), sha],
                       check=True, capture_output=True)
    return path


def pythonpath(tree: pathlib.Path) -> str:
    """``PYTHONPATH`` that imports ``tree``'s packages ahead of the installed ones. Since the
    plugins moved to the top-level ``plugins/`` folder (installed as ``lidar_mitsuba_plugins``),
    that name is a link, outside the tree, to the tree's folder; older trees keep them inside
    ``lidar_mitsuba/plugins``."""
    paths = [str(tree)]
    if "lidar_mitsuba_plugins" in (tree / "pyproject.toml").read_text():
        key = hashlib.sha1(str(tree).encode()).hexdigest()[:12]
        links = pathlib.Path(tempfile.gettempdir()) / f"lidar_mitsuba_ab_path_{key}"
        links.mkdir(exist_ok=True)
        if not (links / "lidar_mitsuba_plugins").exists():
            (links / "lidar_mitsuba_plugins").symlink_to(tree / "plugins")
        paths.append(str(links))
    return os.pathsep.join(paths)


def measure(tree: pathlib.Path, beam: str, depth, shots: int) -> dict:
    env = dict(os.environ, PYTHONPATH=pythonpath(tree))
    out = subprocess.run([sys.executable, "-c", CHILD, beam, str(depth), str(shots)],
                         env=env, cwd=tree, capture_output=True, text=True)
    if out.returncode:
        sys.exit(f"{tree}: {beam} beam, max_depth {depth} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old")
    ap.add_argument("new", nargs="?", default=".")
    ap.add_argument("--shots", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    trees = {"old": checkout(a.old), "new": checkout(a.new)}
    runs = {(v, b, str(d)): [] for v in trees for b, d in CASES}
    for r in range(a.repeats):
        for beam, depth in CASES:
            for version, tree in (trees.items() if r % 2 == 0 else reversed(trees.items())):
                runs[(version, beam, str(depth))].append(measure(tree, beam, depth, a.shots))
    rows = []
    for beam, depth in CASES:
        row = {"beam": beam, "max_depth": str(depth), "shots": a.shots}
        for version in trees:
            got = runs[(version, beam, str(depth))]
            row[version] = {"shots_per_s": a.shots / statistics.median(g["seconds"] for g in got),
                            "loop_shots_per_s": a.shots / statistics.median(g["loop_s"]
                                                                            for g in got),
                            "photons": [g["photons"] for g in got]}
        row["ratio"] = row["new"]["shots_per_s"] / row["old"]["shots_per_s"]
        row["loop_ratio"] = row["new"]["loop_shots_per_s"] / row["old"]["loop_shots_per_s"]
        rows.append(row)
        print(f"{beam} beam, max_depth {depth}, {a.shots} shots, medians of {a.repeats}: "
              f"whole call {row['old']['shots_per_s']:.0f} -> {row['new']['shots_per_s']:.0f} "
              f"shots/s ({row['ratio']:.2f}x); loop {row['old']['loop_shots_per_s']:.0f} -> "
              f"{row['new']['loop_shots_per_s']:.0f} ({row['loop_ratio']:.2f}x)", flush=True)
    doc = {"old": a.old, "new": a.new, "repeats": a.repeats, "rows": rows}
    if a.out:
        pathlib.Path(a.out).write_text(json.dumps(doc, indent=1))
    return doc


if __name__ == "__main__":
    main()
