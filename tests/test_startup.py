"""A fresh process's start-up (issue 43's cold start): Dr.Jit's ``@dr.syntax`` deferred to a
function's first call while the renderer is set up (``lidar_mitsuba.trace.syntax``), and the
start-up's objects frozen out of the garbage collector (``lidar_mitsuba.startup``)."""
import json
import subprocess
import sys

import drjit as dr
import numpy as np
from drjit.llvm import UInt32

from lidar_mitsuba.trace import syntax


def test_deferred_syntax_rewrites_once_on_the_first_call(monkeypatch):
    """Under ``syntax.deferred()`` a ``@dr.syntax`` function (a Python ``while`` on a Dr.Jit
    array, which runs only once rewritten into a symbolic loop) is rewritten by Dr.Jit's own
    ``syntax`` on its first call, once, with the decorator's options, and counts as the
    eagerly rewritten twin does; ``dr.syntax`` is Dr.Jit's again after the block."""
    calls = []
    eager = dr.syntax

    def counting(f=None, **options):
        calls.append(options)
        return eager(f, **options)

    monkeypatch.setattr(dr, "syntax", counting)
    with syntax.deferred():
        @dr.syntax
        def count_up(n):
            i = UInt32(0)
            while i < n:
                i += 1
            return i

        @dr.syntax(recursive=False)
        def count_down(n):
            while n > 0:
                n -= 1
            return n
    assert dr.syntax is counting and calls == []          # restored; nothing rewritten yet
    n = UInt32([0, 1, 3, 7])
    assert count_up(n).numpy().tolist() == [0, 1, 3, 7]
    assert count_up(UInt32([2, 5])).numpy().tolist() == [2, 5]
    assert count_down(UInt32([4, 0])).numpy().tolist() == [0, 0]
    assert calls == [{}, {"recursive": False}]             # each rewritten once

    @counting
    def twin(n):
        i = UInt32(0)
        while i < n:
            i += 1
        return i
    assert np.array_equal(twin(n).numpy(), count_up(n).numpy())


STEP_MODULE = """
import drjit as dr
from drjit.llvm import UInt32


@dr.syntax
def count_up(n):
    i = UInt32(0)
    while i < n:
        i += STEP
    return i
"""


def test_deferred_syntax_rewrites_the_source_as_it_was_defined(tmp_path):
    """A module's file changed between its import and a deferred function's first call (an
    edit, a checkout while a long process runs): the rewriting reads the source as it was
    imported, as the eager rewriting did (here: steps of 1, not the 3 written since)."""
    import importlib.util
    path = tmp_path / "deferred_step.py"
    path.write_text(STEP_MODULE.replace("STEP", "1"))
    spec = importlib.util.spec_from_file_location("deferred_step", path)
    module = importlib.util.module_from_spec(spec)
    with syntax.deferred():
        spec.loader.exec_module(module)
    path.write_text(STEP_MODULE.replace("STEP", "3") + "\n# (longer)\n")
    assert module.count_up(UInt32([2, 5])).numpy().tolist() == [2, 5]


PRB = """
import json
import drjit as dr
import numpy as np
import lidar_mitsuba
mi = lidar_mitsuba.ensure_renderer()
scene = mi.load_dict({
    "type": "scene", "integrator": {"type": "prb", "max_depth": 3},
    "sensor": {"type": "perspective", "fov": 40,
               "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0],
                                                          up=[0, 1, 0]),
               "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}},
               "sampler": {"type": "independent", "sample_count": 2}},
    "emitter": {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}},
    "ball": {"type": "sphere", "radius": 1.0}})
stand_in = hasattr(type(scene.integrator()).sample, "__wrapped__")
image = np.asarray(mi.render(scene, spp=2))
print(json.dumps({"stand_in": stand_in, "own_syntax": dr.syntax is dr.ast.syntax,
                  "finite": bool(np.all(np.isfinite(image))),
                  "corners": [float(image[0, 0].mean()), float(image[-1, -1].mean())],
                  "centre": float(image[4, 4].mean())}))
"""


def test_mitsuba_s_deferred_integrators_render():
    """In a fresh interpreter (this session's tests switch variants with Mitsuba's own
    ``set_variant`` too, which rewrites eagerly): the renderer's set-up deferred Mitsuba's
    differentiable integrators' ``@dr.syntax`` (the ``prb`` integrator's ``sample`` is a
    stand-in), left Dr.Jit's own ``syntax`` in place, and ``prb`` renders on its first call.
    The scene: a constant environment of radiance 1 and a sphere that fills the middle of the
    image, so a corner pixel sees the environment alone (exactly 1)."""
    r = subprocess.run([sys.executable, "-c", PRB], capture_output=True, text=True,
                       timeout=300, check=True)
    last = r.stdout.splitlines()[-1]                  # (after Mitsuba's coloured warnings)
    out = json.loads(last[last.index("{"):])
    assert out["stand_in"] and out["own_syntax"] and out["finite"]
    assert out["corners"] == [1.0, 1.0]
    assert out["centre"] < 0.9                        # the sphere (a diffuse 0.5 albedo)


FROZEN = """
import gc, json
from lidar_mitsuba.startup import frozen_start
out = {"before": gc.isenabled()}
with frozen_start():
    out["inside"] = gc.isenabled()
    junk = [[] for _ in range(1000)]
out["after"], out["frozen"] = gc.isenabled(), gc.get_freeze_count()
gc.disable()
with frozen_start():
    pass
out["kept_off"] = not gc.isenabled()
print(json.dumps(out))
"""


def test_frozen_start_pauses_the_collector_and_freezes_what_is_alive():
    """In a fresh interpreter (a freeze is for a process of our own): the collector is off
    within ``frozen_start``, back on after it with the objects alive frozen, and left off
    where it was off before."""
    r = subprocess.run([sys.executable, "-c", FROZEN], capture_output=True, text=True,
                       timeout=120, check=True)
    out = json.loads(r.stdout)
    assert out["before"] and not out["inside"] and out["after"] and out["kept_off"]
    assert out["frozen"] > 1000


def test_simulate_dem_and_bench_s_granule_rows_start_through_one_helper(monkeypatch, tmp_path):
    """``simulate --dem`` and bench's granule rows (``track_length.measure``) start their
    process through :func:`lidar_mitsuba.startup.granule_process`, first (before the DEM is
    opened or an option checked), so that bench times the start users run."""
    import pytest
    from lidar_mitsuba import startup
    from lidar_mitsuba.cli import main
    from lidar_mitsuba.studies import track_length

    class Started(Exception):
        pass

    calls = []

    def start():
        calls.append(len(calls))
        raise Started

    monkeypatch.setattr(startup, "granule_process", start)
    with pytest.raises(Started):
        track_length.measure(str(tmp_path / "none.tif"), 1.0, "all")
    with pytest.raises(Started):
        main(["simulate", "--dem", str(tmp_path / "none.tif"), "--track", "70,-45,0",
              "--out", str(tmp_path / "o.h5")])
    assert calls == [0, 1]


GRANULE_PROCESS = """
import gc, json, os, sys, threading
from lidar_mitsuba import startup
startup.own_process()
out = {"threshold": gc.get_threshold()[0], "frozen_early": gc.get_freeze_count() > 0,
       "drjit_before": "drjit" in sys.modules}
mi = startup.granule_process()
from lidar_mitsuba import granule_writer, precompile
w = granule_writer._WRITER[0]
out.update(variant=mi.variant(), forked=w.forked, alive=w.alive(),
           loaded=precompile._LOADED_PID[0] == os.getpid(), gc_on=gc.isenabled(),
           again=startup.granule_process() is mi and granule_writer._WRITER[0] is w)
print(json.dumps(out))
"""


def test_granule_process_forks_the_writer_loads_kernels_and_sets_the_renderer_up():
    """In a fresh interpreter (a process of our own): :func:`~lidar_mitsuba.startup.own_process`
    freezes what is alive and raises the youngest generation's threshold; then
    :func:`~lidar_mitsuba.startup.granule_process` forks the writer process (Dr.Jit not loaded
    before it), starts the kernels' loading, sets the default variant up and leaves the
    collector on; a second call starts nothing new."""
    from lidar_mitsuba.startup import GEN0_THRESHOLD
    r = subprocess.run([sys.executable, "-c", GRANULE_PROCESS], capture_output=True,
                       text=True, timeout=300, check=True)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["threshold"] == GEN0_THRESHOLD and out["frozen_early"]
    assert not out["drjit_before"] and out["variant"] == "llvm_ad_mono"
    assert out["forked"] and out["alive"] and out["gc_on"] and out["again"]
    assert out["loaded"]
