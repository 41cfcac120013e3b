"""Shared fixtures. The Mitsuba variant is the one ``import lidar_mitsuba`` chose from
LIDAR_MITSUBA_VARIANT (default llvm_ad_mono), with our plugins registered in it."""
import mitsuba as mi
import numpy as np
import pytest

import lidar_mitsuba  # noqa: F401

VARIANT = mi.variant()        # import lidar_mitsuba applied LIDAR_MITSUBA_VARIANT


@pytest.fixture
def rng():
    """A seeded numpy generator: every test that draws numbers is reproducible."""
    return np.random.default_rng(20131125)


@pytest.fixture(scope="session")
def variant():
    return VARIANT
