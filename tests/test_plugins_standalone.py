"""The plugins stand on their own (issue 28): a plain Mitsuba script, in a fresh interpreter that
never imports ``lidar_mitsuba``, loads ``<bsdf type="ward">`` and ``<integrator
type="pathlength">`` from XML, renders, and traces lidar returns. The checks are exact or
closed-form: a flat Ward plate seen at nadir returns pi f_r cos / 0.9 = (rho_d + rho_s /
(4 alpha^2)) / 0.9 everywhere, and each return's time is its emission time plus the two-way
slant range."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import VARIANT

SCRIPT = r'''
import json, sys
import mitsuba as mi
mi.set_variant(sys.argv[1])
import lidar_mitsuba_plugins                     # registers ward, pathlength, volpathlength

XML = """<scene version="3.0.0">
  <integrator type="pathlength">
    <float name="altitude_m" value="496000"/>
    <float name="footprint_sigma_m" value="2.5"/>
    <float name="pulse_sigma_ns" value="0.5"/>
  </integrator>
  <sensor type="orthographic">
    <transform name="to_world">
      <lookat origin="0, 0, 10" target="0, 0, 0" up="0, 1, 0"/>
      <scale x="20" y="20"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
      <rfilter type="box"/></film>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="200"/></transform>
    <bsdf type="ward"><float name="rho_d" value="0.9"/><float name="rho_s" value="0.05"/>
      <float name="alpha" value="0.3"/></bsdf>
  </shape>
</scene>"""
scene = mi.load_string(XML)
image = mi.render(scene)
returns = scene.integrator().trace(scene, shot_x_m=[0.0, 3.0], shot_y_m=[0.0, -2.0],
                                   paths_per_shot=4096, seed=7)
import numpy as np
dx = returns.x_m - np.array([0.0, 3.0])[returns.shot]      # from the shot's footprint centre
dy = returns.y_m - np.array([0.0, -2.0])[returns.shot]
slant_m = (dx ** 2 + dy ** 2 + 496000.0 ** 2) ** 0.5
print("RESULT " + json.dumps({
    "pipeline_imported": any(m == "lidar_mitsuba" or m.startswith("lidar_mitsuba.")
                             for m in sys.modules),
    "image": [float(v) for v in image.numpy()[..., 0].ravel()],
    "n_returns": len(returns), "n_shots": returns.n_shots,
    "weights": [float(returns.weight.min()), float(returns.weight.max())],
    "t_emit_ns": (returns.time_ns - 2.0 * slant_m / lidar_mitsuba_plugins.constants.C_M_PER_NS
                  ).tolist(),
    "footprint_r2_m2": float((dx ** 2 + dy ** 2).mean()),
}))
'''


@pytest.fixture(scope="module")
def standalone():
    env = dict(os.environ)           # DRJIT_LIBLLVM_PATH: the machine's usable libLLVM
    out = subprocess.run([sys.executable, "-I", "-c", SCRIPT, VARIANT], env=env,
                         capture_output=True, text=True, timeout=300, cwd=os.path.dirname(__file__))
    assert out.returncode == 0, out.stderr[-3000:]
    line = next(t for t in out.stdout.splitlines() if t.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])       # (mi.render prints its progress too)


def test_plain_mitsuba_script_never_imports_the_pipeline(standalone):
    assert standalone["pipeline_imported"] is False


def test_rendered_ward_plate_is_the_closed_form(standalone):
    expected = (0.9 + 0.05 / (4 * 0.3 ** 2)) / 0.9           # 1.15432...
    np.testing.assert_allclose(standalone["image"], expected, rtol=2e-6)


def test_traced_returns_have_exact_weights_and_times(standalone):
    """Every path hits the 400 m plate (the footprint's 2.5 m sigma), each with the plate's
    weight. Emission time = return time - two-way slant range / c must be N(0, 0.5 ns): its mean
    within 5 standard errors (0.5 / sqrt(8192) ns) and its variance within 5 standard errors of
    the sample variance (sigma^2 sqrt(2 / n)); the footprint's mean r^2 is 2 sigma^2 = 12.5 m^2
    within 5 standard errors (r^2 is exponential: SE 12.5 / sqrt(n))."""
    n = 2 * 4096
    assert standalone["n_shots"] == 2 and standalone["n_returns"] == n
    expected = (0.9 + 0.05 / (4 * 0.3 ** 2)) / 0.9
    np.testing.assert_allclose(standalone["weights"], expected, rtol=2e-6)
    t = np.asarray(standalone["t_emit_ns"])
    assert abs(t.mean()) < 5 * 0.5 / np.sqrt(n)
    assert abs(t.var() - 0.25) < 5 * 0.25 * np.sqrt(2 / n)
    assert abs(standalone["footprint_r2_m2"] - 12.5) < 5 * 12.5 / np.sqrt(n)
