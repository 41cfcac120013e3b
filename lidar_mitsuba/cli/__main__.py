"""``python -m lidar_mitsuba.cli``: the command line, as ``lidar-mitsuba`` runs it."""
import sys

from lidar_mitsuba_cli import main

sys.exit(main())
