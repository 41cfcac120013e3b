"""``python -m lidar_mitsuba.cli``: the command line, as ``lidar-mitsuba`` runs it."""
import sys

from lidar_mitsuba_cli import main

if __name__ == "__main__":       # not when imported (the documentation imports every module)
    sys.exit(main())
