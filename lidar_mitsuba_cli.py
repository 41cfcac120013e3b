"""Launcher of the ``lidar-mitsuba`` command.

It lives outside the ``lidar_mitsuba`` package so that an environment problem (no usable
libLLVM, found when a command first needs the renderer) is reported as one line instead of a
traceback.
"""
import sys


def main(argv=None) -> int:
    try:
        from lidar_mitsuba.cli import main as cli_main
    except ImportError as e:
        sys.stderr.write(f"lidar-mitsuba: error: {e}\n")
        return 1
    if argv is None:             # the command's own process (not a caller's): the imports'
        import gc                # objects live as long as it, so the collector skips them,
        gc.freeze()              # and young objects are collected less often (a granule's
        gc.set_threshold(10000, 10, 10)     # collections: 0.21 s -> 0.10 s)
    from lidar_mitsuba.trace.variant import RendererUnavailable
    try:
        return cli_main(argv)
    except RendererUnavailable as e:     # no usable libLLVM or variant, found on first use
        sys.stderr.write(f"lidar-mitsuba: error: {e}\n")
        return 1
    except BrokenPipeError:          # e.g. `lidar-mitsuba stats f.h5 | head`
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
