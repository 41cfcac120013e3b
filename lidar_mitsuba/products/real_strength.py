"""Strong or weak for the beams of a real file that says neither: no group carries
``atlas_beam_type`` and ``orbit_info/sc_orient`` is gone (subsetting tools drop both; e.g. a
test subset of ATL08 holding only ``gtxx/land_segments``). The beams of a pair share one
place and one sky, and ATLAS's strong beam carries four times the weak one's energy (the
design's 4:1, :data:`~lidar_mitsuba.instrument.ATLAS`), so within a pair the beam with the
higher median signal is the strong one; the spacecraft's orientation puts the strong beams
all left or all right (:func:`~lidar_mitsuba.geotrack.beam_layout`), so every pair the file
holds must agree. Pure (numpy).
"""
from __future__ import annotations

import numpy as np

from ..constants import ParameterError

PAIR_RATIO_MIN = 2.0
"""The least ratio of a pair's median signal rates [strong / weak] read as a strength: half
the design's 4:1 (ESTIMATE: the two beams' surfaces and their clouds differ by some tens of
per cent along a pair 90 m apart; a ratio under 2 says the rates are not the energies')."""


def infer(beams: list, path) -> int:
    """Set ``strength``, ``strength_from`` (``signal rates``) and, where unset (0), ``spot``
    of every beam whose strength is None from the pairs' median signal rates; return the
    orientation they imply (0 backward: left strong; 1 forward: right strong). Raises
    ``ParameterError`` (``like``) in one line when no pair of the file tells."""
    from ..geotrack import beam_layout
    by_name = {b.name: b for b in beams}
    ratios = []
    for k in (1, 2, 3):
        left, right = by_name.get(f"gt{k}l"), by_name.get(f"gt{k}r")
        if left is None or right is None:
            continue
        sl, sr = _median_signal(left), _median_signal(right)
        if sl is not None and sr is not None and sl > 0 and sr > 0:
            ratios.append(sl / sr)
    tells = [r for r in ratios if r >= PAIR_RATIO_MIN or r <= 1.0 / PAIR_RATIO_MIN]
    if not tells or (min(tells) < 1.0 < max(tells)):
        said = ", ".join(f"{r:.2f}" for r in ratios) or "no pair with signal rates in both"
        raise ParameterError("like", f"{path}: neither atlas_beam_type nor sc_orient says "
                             "which beams are strong, and the pairs' signal rates do not "
                             f"(left / right: {said})")
    orient = 0 if tells[0] > 1.0 else 1
    layout = {b.name: b for b in beam_layout(orient)}
    for b in beams:
        if b.strength is None:
            b.strength, b.strength_from = layout[b.name].strength, "signal rates"
            b.spot = b.spot or layout[b.name].spot
    return orient


def _median_signal(b) -> float | None:
    s = b.signal_per_shot
    if s is None or not np.isfinite(s).any():
        return None
    return float(np.nanmedian(s))


def missing_words(beams: list) -> str | None:
    """The missing line's words for beams whose strength the signal rates gave, or None."""
    names = [b.name for b in beams if b.strength_from == "signal rates"]
    if not names:
        return None
    return (f"atlas_beam_type on {', '.join(names)} (strength from the pairs' signal rates, "
            f"strong >= {PAIR_RATIO_MIN:g}x weak)")


def orientation(beams: list, orient: int | None) -> tuple[int | None, str | None]:
    """``(orientation, note)``: the one the beams' ``atlas_beam_type`` implies (a strong left
    beam: 0, backward; a strong right one: 1, forward), trusted over ``sc_orient`` (a clip
    tool can rewrite it; a twin lays its beams out and picks ``--beams strong`` by it), with a
    note for the file's line where they disagree; ``(orient, None)`` where no beam type
    says one orientation."""
    implied = {0 if b.name.endswith("l") == (b.strength == "strong") else 1
               for b in beams if b.strength_from == "atlas_beam_type"}
    if len(implied) != 1:
        return orient, None
    o = implied.pop()
    if orient is None or o == orient:
        return o, None
    return o, (f"a true orbit_info/sc_orient ({orient} contradicts atlas_beam_type: "
               f"{o} taken)")
