"""Pure stages import without a renderer (issue 33): no module outside ``trace/`` (and the
plugins) loads Mitsuba or Dr.Jit when it is imported, reading our products needs neither, and
the renderer is set up the first time something traces.

sys.modules is per process and this suite's conftest has set the renderer up, so every check
runs in a fresh interpreter, with an unusable ``LIDAR_MITSUBA_VARIANT``: a module that still
set the renderer up at import would fail loudly rather than pass.
"""
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PKG = ROOT / "lidar_mitsuba"
#: the renderer's own modules: they set it up when imported
RENDERER_MODULES = ("lidar_mitsuba.trace.scene", "lidar_mitsuba.trace.materials",
                    "lidar_mitsuba.trace.pilot")

PROBE = """
import importlib, json, sys
out = {}
for name in sys.argv[1:]:
    importlib.import_module(name)
    out[name] = sorted(m for m in ('mitsuba', 'drjit', 'mitransient') if m in sys.modules)
    if out[name]:
        break                       # later modules would be blamed for this one
print(json.dumps(out))
"""


def _modules() -> list[str]:
    out = []
    for p in sorted(PKG.rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__main__":           # runs the command line when imported
            continue
        if parts[-1] == "__init__":
            parts.pop()
        out.append(".".join(parts))
    return out


def _env() -> dict:
    return dict(os.environ, LIDAR_MITSUBA_VARIANT="llvm_ad_nope")


def _probe(names: list[str]) -> dict:
    r = subprocess.run([sys.executable, "-c", PROBE, *names], capture_output=True, text=True,
                       timeout=300, cwd=ROOT, env=_env())
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


GROUPS = sorted({".".join(m.split(".")[:2]) for m in _modules()})


@pytest.mark.parametrize("group", GROUPS)
def test_modules_import_without_a_renderer(group):
    """Each package's modules, in one fresh interpreter per package (the first module that
    pulls the renderer in is named); only trace's scene, materials and pilot may."""
    names = [m for m in _modules() if (m == group or m.startswith(group + "."))
             and m not in RENDERER_MODULES]
    found = _probe(names)
    assert all(v == [] for v in found.values()), {k: v for k, v in found.items() if v}
    assert len(found) == len(names)


def test_the_front_door_is_lazy_and_sets_the_renderer_up_on_first_use():
    code = ("import sys, lidar_mitsuba as lm\n"
            "names = [lm.ParameterError, lm.Instrument.atlas(), lm.read_atl03, lm.SurfaceSpec,\n"
            "         lm.water_bsdf, lm.simulate, lm.simulate_granule]\n"
            "print(sorted(m for m in ('mitsuba', 'drjit') if m in sys.modules))\n"
            "mi = lm.ensure_renderer()\n"
            "print(mi.variant(), callable(lm.simulate), lm.load_scene.__name__)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    first, second = r.stdout.strip().splitlines()
    assert first == "[]"
    assert second == "llvm_ad_mono True load_scene"


def test_stats_and_segments_run_without_a_renderer(tmp_path):
    """A file written here (a run's ATL03) is read by ``stats`` and fitted by ``segments`` in
    processes that cannot set the renderer up (only a libLLVM 15 on offer)."""
    import lidar_mitsuba as lm
    res = lm.simulate(surface=lm.SurfaceSpec(kind="flat"), shots=300, seed=1, progress=False)
    path = lm.write_atl03(res, tmp_path / "run.h5")
    fake = tmp_path / "libLLVM-15.so"
    fake.touch()
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(fake))
    for cmd in (["stats", str(path), "--json"], ["segments", str(path), "--json"]):
        r = subprocess.run([sys.executable, "-m", "lidar_mitsuba_cli", *cmd], env=env,
                           capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert r.returncode == 0, (cmd, r.stderr)
        assert json.loads(r.stdout)
    beam = lm.read_atl03(path)
    assert np.allclose(beam["h_m"], res.h_m)


#: what only the writer process needs (h5py, the product writers): issue 43's cold start
WRITER_ONLY = ("h5py", "lidar_mitsuba.granule_products", "lidar_mitsuba.products.atl03",
               "lidar_mitsuba.products.atl06", "lidar_mitsuba.products.h5write",
               "lidar_mitsuba.products.h5template", "lidar_mitsuba.products.metadata")


def test_the_simulating_side_imports_no_writer():
    """The simulating process of a granule run (``simulate --dem``, bench's granule row)
    imports neither h5py nor the product writers before its first granule: the writer process
    imports them itself, after its fork; ``granule.write_atl03`` and ``write_atl06`` stay,
    importing the writers when called."""
    code = ("import sys\n"
            "import lidar_mitsuba.granule, lidar_mitsuba.granule_writer\n"
            "import lidar_mitsuba.studies.track_length, lidar_mitsuba.cli.simulate\n"
            f"print([m for m in {WRITER_ONLY!r} if m in sys.modules])\n"
            "from lidar_mitsuba import granule\n"
            "print(granule.write_atl03.__module__, granule.write_atl06.__module__)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300, cwd=ROOT, env=_env())
    assert r.returncode == 0, r.stderr
    first, second = r.stdout.strip().splitlines()
    assert first == "[]"
    assert second == "lidar_mitsuba.granule lidar_mitsuba.granule"
