"""Modules deferred to their first use (lidar_mitsuba.deferred): a stand-in that an import
statement finds without loading anything, loads the real module on its first attribute, and
leaves rasterio's S3 sessions as they were (issue 43: a cold granule's start)."""
import subprocess
import sys
import textwrap

import pytest

from lidar_mitsuba import deferred


@pytest.fixture
def toy(tmp_path, monkeypatch):
    """A package that counts its imports in ``sys.toy_loads``, with a submodule."""
    pkg = tmp_path / "toy_deferred_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("import sys\nsys.toy_loads = getattr(sys, 'toy_loads', 0) + 1"
                                     "\nVALUE = 42\n")
    (pkg / "sub.py").write_text("WHO = 'sub'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "toy_loads", 0, raising=False)
    yield "toy_deferred_pkg"
    for name in ("toy_deferred_pkg", "toy_deferred_pkg.sub"):
        sys.modules.pop(name, None)


def test_a_deferred_module_loads_on_its_first_attribute(toy):
    stand_in = deferred.defer(toy)
    import toy_deferred_pkg                      # found in sys.modules: nothing runs
    assert toy_deferred_pkg is stand_in and sys.toy_loads == 0
    assert toy_deferred_pkg is not None
    assert toy_deferred_pkg.VALUE == 42 and sys.toy_loads == 1
    real = sys.modules[toy]
    assert real is not stand_in and real.VALUE == 42
    assert stand_in.VALUE == 42 and sys.toy_loads == 1     # loaded once, handed on
    assert deferred.defer(toy) is real                      # imported already: left alone


def test_a_submodule_import_loads_the_deferred_package(toy):
    deferred.defer(toy)
    from toy_deferred_pkg import sub
    assert sub.WHO == "sub" and sys.toy_loads == 1
    assert deferred.defer("no_such_module_for_lidar_mitsuba") is None


def test_rasterio_without_boto3_until_an_s3_session_needs_it():
    """In a fresh interpreter (this one may have boto3 already): rasterio as our DEMs open
    it imports no botocore, and an ``s3://`` path still gets rasterio's AWS session (the
    stand-in's loading is the test above's)."""
    pytest.importorskip("boto3")
    code = textwrap.dedent("""
        import sys
        from lidar_mitsuba import deferred
        deferred.rasterio()
        from rasterio.session import Session
        print('botocore' in sys.modules, Session.cls_from_path('s3://b/k.tif').__name__,
              Session.cls_from_path('/tmp/k.tif').__name__, 'botocore' in sys.modules)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False AWSSession DummySession False"


def test_dems_open_rasterio_through_it(monkeypatch):
    from lidar_mitsuba.ground import dem
    monkeypatch.setattr(deferred, "rasterio", lambda: "deferred")
    assert dem._rasterio() == "deferred"
