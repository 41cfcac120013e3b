"""Mitsuba variant selection (lidar_mitsuba.trace.variant) and plugin registration
(lidar_mitsuba_plugins).

The conftest activates the session's variant once; tests here that switch variants put it
back afterwards (the ``restore_variant`` fixture), whatever happens."""
import os
import re
import subprocess
import sys
import textwrap

import drjit as dr
import mitsuba as mi
import pytest

import lidar_mitsuba
import lidar_mitsuba_plugins as P


@pytest.fixture
def restore_variant(variant):
    yield                                   # the test's objects are released by now
    lidar_mitsuba.set_variant(variant)
    assert mi.variant() == variant


def plugins_load():
    """Both plugins load as objects of the *active* variant's classes (the plugin files were
    executed under this variant, not reused from another one)."""
    bsdf = mi.load_dict({"type": "ward"})
    integ = mi.load_dict({"type": "pathlength"})
    assert isinstance(bsdf, mi.BSDF) and type(bsdf).__name__ == "WardBSDF"
    assert isinstance(integ, mi.SamplingIntegrator)
    assert type(integ).__name__ == "PathLengthIntegrator"
    return bsdf, integ


def test_session_variant_is_active_with_plugins(variant):
    assert mi.variant() == variant
    assert lidar_mitsuba.set_variant(variant) == variant       # re-selecting is a no-op
    assert variant in P._registered
    plugins_load()


@pytest.mark.parametrize("name", ["nonsense", "llvm_ad_nope", "cuda_ad_nope", ""] + [
    v for v in ("llvm_ad_spectral", "llvm_ad_mono_polarized") if v in mi.variants()])
def test_unknown_variant_is_refused_naming_it(name, variant):
    with pytest.raises(ValueError, match=re.escape(repr(name))):
        lidar_mitsuba.set_variant(name)
    assert mi.variant() == variant                              # nothing changed


@pytest.mark.parametrize("name", [v for v in ("scalar_rgb", "scalar_mono", "scalar_spectral")
                                  if v in mi.variants()] or ["scalar_rgb"])
def test_scalar_variants_are_refused_naming_them(name, variant):
    """Scalar variants cannot run the vectorised plugins: refused even when Mitsuba has them
    (a scalar variant Mitsuba lacks is refused as unknown)."""
    with pytest.raises(ValueError, match=re.escape(repr(name))):
        lidar_mitsuba.set_variant(name)
    assert mi.variant() == variant


@pytest.mark.skipif(dr.has_backend(dr.JitBackend.CUDA), reason="a CUDA backend exists here")
@pytest.mark.parametrize("name", ["cuda_ad_mono", "cuda_ad_rgb"])
def test_cuda_is_refused_without_a_gpu(name, variant):
    if name not in mi.variants():
        pytest.skip(f"{name} is not compiled into this Mitsuba")
    with pytest.raises(ValueError, match=re.escape(repr(name)) + ".*CUDA"):
        lidar_mitsuba.set_variant(name)
    assert mi.variant() == variant


def test_llvm_variants_are_unusable_without_libllvm(monkeypatch, variant):
    """Where ``import lidar_mitsuba`` found no libLLVM (a GPU machine; DRJIT_LIBLLVM_PATH is
    then os.devnull) the LLVM variants are not offered, and asking for one says why."""
    assert "llvm_ad_mono" in lidar_mitsuba.trace.variant.usable_variants()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", os.devnull)
    assert not any(v.startswith("llvm") for v in lidar_mitsuba.trace.variant.usable_variants())
    with pytest.raises(ValueError, match="'llvm_ad_rgb' needs libLLVM"):
        lidar_mitsuba.set_variant("llvm_ad_rgb")
    assert mi.variant() == variant


def test_switching_variants_keeps_plugins_registered_in_each(variant, restore_variant):
    """llvm_ad_mono -> llvm_ad_rgb -> llvm_ad_mono, through set_variant and through Mitsuba's
    own mi.set_variant (the variant callback): in each the plugins load as that variant's
    classes."""
    if "llvm_ad_rgb" not in mi.variants():
        pytest.skip("llvm_ad_rgb is not compiled into this Mitsuba")
    assert lidar_mitsuba.set_variant("llvm_ad_mono") == "llvm_ad_mono"
    mono_bsdf_class = mi.BSDF
    mono = plugins_load()
    assert lidar_mitsuba.set_variant("llvm_ad_rgb") == "llvm_ad_rgb"
    assert mi.variant() == "llvm_ad_rgb" and "llvm_ad_rgb" in P._registered
    rgb = plugins_load()
    assert mi.BSDF is not mono_bsdf_class                       # a different class hierarchy
    assert type(rgb[0]) is not type(mono[0]) and not isinstance(rgb[0], mono_bsdf_class)
    lidar_mitsuba.set_variant("llvm_ad_mono")
    assert mi.variant() == "llvm_ad_mono"
    plugins_load()
    mi.set_variant("llvm_ad_rgb")                               # Mitsuba's own switch
    plugins_load()
    mi.set_variant("llvm_ad_mono")
    plugins_load()


def test_fresh_process_registers_in_the_active_variant_and_on_every_switch():
    """In a fresh interpreter: ``import lidar_mitsuba`` keeps a variant the user activated
    before (llvm_ad_rgb) and registers the plugins there; a later switch with Mitsuba's own
    mi.set_variant registers them in the new variant (the callback), which no earlier call
    had done in that process."""
    if "llvm_ad_rgb" not in mi.variants():
        pytest.skip("llvm_ad_rgb is not compiled into this Mitsuba")
    code = textwrap.dedent("""
        import mitsuba as mi
        mi.set_variant("llvm_ad_rgb")
        import lidar_mitsuba
        import lidar_mitsuba_plugins as P
        assert mi.variant() == "llvm_ad_rgb", mi.variant()
        assert P._registered == {"llvm_ad_rgb"}, P._registered
        mi.load_dict({"type": "ward"}); mi.load_dict({"type": "pathlength"})
        mi.set_variant("llvm_ad_mono")
        assert P._registered == {"llvm_ad_rgb", "llvm_ad_mono"}, P._registered
        mi.load_dict({"type": "ward"}); mi.load_dict({"type": "pathlength"})
        print("ok")
    """)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [os.path.dirname(os.path.dirname(lidar_mitsuba.__file__)), env.get("PYTHONPATH", "")])
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr
