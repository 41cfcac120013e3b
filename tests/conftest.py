"""Shared fixtures. The Mitsuba variant is chosen once here (LIDAR_MITSUBA_VARIANT, default
llvm_ad_mono); ``import lidar_mitsuba`` registers our plugins in it."""
import os

import numpy as np
import pytest

import lidar_mitsuba

VARIANT = os.environ.get("LIDAR_MITSUBA_VARIANT", lidar_mitsuba.DEFAULT_VARIANT)
lidar_mitsuba.set_variant(VARIANT)


@pytest.fixture
def rng():
    """A seeded numpy generator: every test that draws numbers is reproducible."""
    return np.random.default_rng(20131125)


@pytest.fixture(scope="session")
def variant():
    return VARIANT
