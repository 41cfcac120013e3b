"""The ground under the track: terrain, spectra, DEMs, surfaces, snow, water and BRDFs. Pure at import (no Mitsuba, no Dr.Jit)."""
