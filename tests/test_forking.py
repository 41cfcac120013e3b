"""The writer process's fork (lidar_mitsuba.forking, issue 43's cold start): what refuses a
fork, and the forked child's handle. The granule files a forked writer writes are compared
with the inline writer's in tests/test_granule.py."""
import os
import subprocess
import time

import h5py
import pytest

from lidar_mitsuba import forking


def test_a_fork_is_refused_with_an_hdf5_file_or_pyproj_open():
    """An open HDF5 file and a loaded pyproj (PROJ's SQLite database open) each refuse a fork,
    by name (this process has threads and Dr.Jit too: every reason is listed)."""
    import pyproj  # noqa: F401
    with h5py.File("refusal.h5", "w", driver="core", backing_store=False):
        reasons = forking.refusal()
        assert "an HDF5 file is open" in reasons
    assert "pyproj is loaded" in reasons and "Dr.Jit is loaded" in reasons


def test_the_forked_child_s_handle_waits_times_out_and_reaps():
    """``Forked``: ``poll`` is ``None`` while the child runs, ``wait`` with a timeout raises
    ``subprocess.TimeoutExpired`` and then returns the child's exit code (0 when its target
    returns; the code the target ends it with otherwise), and the child is reaped.
    (The children here print nothing and take no lock this process's threads could hold.)"""
    sleeper = forking.fork(time.sleep, 0.5)
    assert sleeper.pid != os.getpid() and sleeper.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        sleeper.wait(timeout=0.01)
    assert sleeper.wait(timeout=30) == 0 and sleeper.poll() == 0
    assert forking.fork(os._exit, 3).wait() == 3
    with pytest.raises(ChildProcessError):
        os.waitpid(sleeper.pid, os.WNOHANG)       # (reaped: no zombie left)
