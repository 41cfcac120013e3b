"""libLLVM detection and the instrument's parameter checks."""
import os
import subprocess
import sys

import pytest

from lidar_mitsuba.trace import libllvm as _llvm
from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.instrument import Instrument


@pytest.mark.parametrize("path,major", [
    ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", 15),
    ("/usr/lib/llvm-17/lib/libLLVM.so", 17),
    ("/opt/libLLVM.so", None),
])
def test_llvm_version_from_name(path, major):
    assert _llvm.llvm_major_version(path) == major


def test_find_libllvm_prefers_newest_usable(tmp_path):
    files = {v: tmp_path / f"libLLVM-{v}.so" for v in (14, 15, 16, 18, 19)}
    for f in files.values():
        f.touch()
    assert _llvm.find_libllvm([str(f) for f in files.values()]) == str(files[19])
    bad = [str(files[v]) for v in (14, 15, 16)]
    assert _llvm.find_libllvm(bad) is None


def test_renderer_refuses_bad_llvm_without_aborting(tmp_path):
    """With only libLLVM 15 on offer, `import lidar_mitsuba` still works (it loads no renderer);
    the first use of the renderer raises an ImportError (RendererUnavailable) that says what
    to install, and a simulation from the command line is one line, exit 1; the interpreter
    is never aborted by LLVM. Reading a file (`stats`) needs no renderer."""
    fake = tmp_path / "libLLVM-15.so"
    fake.touch()
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(fake))
    r = subprocess.run([sys.executable, "-c", "import lidar_mitsuba as lm; lm.Instrument()"],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-c", "import lidar_mitsuba as lm; lm.ensure_renderer()"],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert "RendererUnavailable" in r.stderr and "libllvm19" in r.stderr
    r = subprocess.run([sys.executable, "-m", "lidar_mitsuba_cli", "simulate", "--surface",
                        "flat", "--shots", "10", "--out", str(tmp_path / "x.h5")], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "libllvm19" in r.stderr
    assert not (tmp_path / "x.h5").exists()


def test_variant_from_the_environment():
    """LIDAR_MITSUBA_VARIANT picks the variant when the renderer is set up; an unusable one is
    one ImportError line naming the variable (a CUDA variant on a machine without a GPU,
    too)."""
    def imported(variant):
        env = dict(os.environ, LIDAR_MITSUBA_VARIANT=variant)
        return subprocess.run([sys.executable, "-c", "import lidar_mitsuba as lm; "
                               "print(lm.ensure_renderer().variant())"], env=env,
                              capture_output=True, text=True, timeout=120)
    r = imported("llvm_ad_rgb")
    assert r.returncode == 0 and r.stdout.strip() == "llvm_ad_rgb"
    r = imported("llvm_ad_nope")
    assert r.returncode == 1 and "LIDAR_MITSUBA_VARIANT: variant 'llvm_ad_nope'" in r.stderr


def test_a_cuda_variant_needs_no_libllvm(monkeypatch):
    """With a CUDA variant asked for and no libLLVM found, the check passes and points
    Dr.Jit at no library rather than at the system's bad one; without one it still refuses."""
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    monkeypatch.setattr(_llvm, "find_libllvm", lambda candidates=None: None)
    assert _llvm.ensure_libllvm(required=False) is None
    assert os.environ["DRJIT_LIBLLVM_PATH"] == os.devnull
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    with pytest.raises(ImportError, match="libllvm19"):
        _llvm.ensure_libllvm()


def test_import_sets_usable_llvm():
    path = os.environ["DRJIT_LIBLLVM_PATH"]
    assert (_llvm.llvm_major_version(path) or 99) >= _llvm.MIN_LLVM_MAJOR


def test_instrument_defaults_are_the_papers():
    strong, weak = Instrument(beam="strong"), Instrument(beam="weak")
    assert (strong.signal_photons, strong.channels, strong.anodes_per_channel) == (8.17, 16, 1)
    assert (weak.signal_photons, weak.channels, weak.anodes_per_channel) == (2.04, 4, 4)
    assert strong.footprint_sigma_m == 2.5
    assert abs(strong.pulse_sigma_ns - 1 / 2.35482) < 1e-5
    assert abs(strong.ranging_sigma_m - 0.06366) < 1e-5          # c sigma_t / 2
    assert strong.prf_hz * strong.shot_spacing_m == 7000.0        # ground speed [m/s]
    assert (strong.pde, strong.fill_factor, strong.dead_time_ns, strong.altitude_m) == (0.5, 0.8, 3.0, 496e3)


@pytest.mark.parametrize("field,value", [
    ("pde", 1.2), ("fill_factor", -0.1), ("dead_time_ns", -1.0), ("signal_photons", float("nan")),
    ("channels", 5), ("pulse_fwhm_ns", -1.0), ("footprint_diameter_m", -1.0), ("altitude_m", 0.0),
    ("prf_hz", 0.0), ("beam", "medium"), ("anodes", 0), ("fov_diameter_m", 0.0),
])
def test_instrument_refuses_out_of_range(field, value):
    with pytest.raises(ParameterError) as e:
        Instrument(**{field: value})
    assert e.value.name == field and str(e.value).startswith(field)
