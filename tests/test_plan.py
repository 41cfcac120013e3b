"""A run is a plan and a stream (issue 33): ``lm.plan`` decides everything before a photon is
traced and returns a frozen, printable ``RunPlan``; ``lm.stream`` traces and detects it;
``lm.assemble`` makes the result; ``lm.simulate`` is exactly the three."""
import dataclasses

import numpy as np
import pytest

import lidar_mitsuba as lm


def test_plan_stream_assemble_is_simulate_to_the_bit():
    kw = dict(surface=lm.SurfaceSpec(kind="fractal", p=1.8, size_m=256.0), shots=400, seed=3,
              progress=False)
    p = lm.plan(**kw)
    res = lm.assemble(p, lm.stream(p))
    ref = lm.simulate(**kw)
    assert np.array_equal(res.h_m, ref.h_m) and np.array_equal(res.detections.shot,
                                                               ref.detections.shot)
    assert res.config["max_depth"] == p.max_depth and res.config["plan"] == p.describe()


def test_the_plan_is_frozen_and_says_what_it_chose():
    p = lm.plan(scene="scenes/melt_pond.xml", params={"depth_m": "2"}, shots=200,
                progress=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.max_depth = 1
    text = str(p)
    assert "mediapathlength" in text and "interfaces" in text and "200 shots" in text
    assert p.max_depth == 8 and p.paths_per_shot >= 8
    assert p.x.shape == p.z_ref.shape == (200,)
