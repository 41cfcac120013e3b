"""Launcher of the ``lidar-mitsuba`` command.

It lives outside the ``lidar_mitsuba`` package so that an environment problem found while the
package is imported (no usable libLLVM) is reported as one line instead of a traceback.
"""
import sys


def main(argv=None) -> int:
    try:
        from lidar_mitsuba.cli import main as cli_main
    except ImportError as e:
        sys.stderr.write(f"lidar-mitsuba: error: {e}\n")
        return 1
    return cli_main(argv)


if __name__ == "__main__":
    sys.exit(main())
