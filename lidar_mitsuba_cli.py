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
        from lidar_mitsuba.startup import own_process       # objects live as long as it,
        own_process()            # so the collector skips them; young objects are collected
                                 # less often (bench's rows do the same)
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
