"""The realism matrix's verdict on a beam whose segments are all cloudy
(:func:`~lidar_mitsuba.studies.realism.verdict`): the model with the cloud given, or with every
cloud the file's own inputs allow (:func:`~lidar_mitsuba.studies.realism_inputs.cloud_alternatives`:
the optical depth each of its apparent reflectances implies; where ATL09 found several layers
and places only the lowest, the depth all in it or all above the band).

The rule, written from the verdict's own tolerances, not from any file: a quantity's
predictions over those clouds *bracket* it. Where the cloud the matrix takes (the first
reflectance's) agrees, the beam *agrees*; where no cloud of the bracket can agree (the
bracket misses the agreement range), it *disagrees*; where the bracket reaches the agreement
range and is wider than the verdict can tell apart (its ends further apart than the agreement
range allows of two predictions of one measurement: ``max / min > min(hi, 1 / lo)``), the
verdict is *cloud uncertain*, naming the datasets, their optical depths and the bracket: the
file does not pin the cloud down well enough for the quantity to test the model. Otherwise it
disagrees (the model is wrong for a cloud the file pins down).
"""
from __future__ import annotations

from .realism import BACKGROUND_AGREES, SIGNAL_AGREES, _fmt, _ratio

QUANTITIES = (("background", "background_cloudy_hz", "background_hz", BACKGROUND_AGREES),
              ("signal", "signal_cloudy", "signal", SIGNAL_AGREES))
"""Each quantity judged: its name, the measured key, the alternatives' key, its agreement
range (predicted / measured)."""


def spread_limit(agrees: tuple[float, float]) -> float:
    """The widest ratio of two predictions of one measured value that the agreement range
    ``(lo, hi)`` cannot tell apart: ``min(hi, 1 / lo)`` (background (0.5, 2): 2; signal (0.7,
    1.4): 1.4). Predictions further apart than this cannot both agree with one measurement."""
    lo, hi = agrees
    return min(hi, 1.0 / lo)


def judge(predictions: list[float], measured: float | None,
          agrees: tuple[float, float]) -> dict | None:
    """One quantity over the clouds a file allows: ``predictions`` (the matrix's own cloud
    first), ``measured``; None where nothing is measured. Returns ``{"ratio"`` (the first's
    predicted / measured), ``"lo", "hi"`` (the bracket's ratios), ``"agrees"`` (the first
    within ``agrees``), ``"reaches"`` (the bracket overlaps ``agrees``), ``"wide"`` (its ends
    further apart than :func:`spread_limit`)``}``."""
    if measured is None or not measured > 0 or not predictions:
        return None
    lo, hi = agrees
    r = [p / measured for p in predictions]
    a, b = min(r), max(r)
    return {"ratio": r[0], "lo": a, "hi": b, "agrees": lo <= r[0] <= hi,
            "reaches": b >= lo and a <= hi, "wide": b / a > spread_limit(agrees)}


def cloudy_verdict(row: dict) -> tuple[str, str]:
    """``(verdict, reason)`` of a beam whose segments are all cloudy, against the model with
    the cloud given or the ones its file implies (module docstring). ATL06's ``r_eff`` and
    ATL07's ``height_segment_asr_calc`` are made from the photons whose rate is the signal, so
    a signal predicted with their cloud is circular: with ``r_eff`` the signal is not compared;
    ``asr_calc``'s cloud only widens the bracket (the inputs disagree), said so."""
    m, p = row["measured"], row["predicted"]
    bg = _ratio(p["background_cloudy_hz"], m["background_cloudy_hz"])
    sig = _ratio(p["signal_cloudy"], m["signal_cloudy"])
    row["background_cloudy_ratio"], row["signal_cloudy_ratio"] = bg, sig
    c = row.get("cloud") or {}
    alts = p.get("cloud_alternatives") or [{
        "dataset": "r_eff" if row["product"] == "ATL06" else "reflectance",
        "from": "the product's", "circular": row["product"] == "ATL06", "above_band": False,
        "optical_depth": c.get("optical_depth"), "signal": p["signal_cloudy"],
        "background_hz": p["background_cloudy_hz"]}]
    if c.get("from") != "the file's reflectance":
        return _given(bg, sig)
    head = alts[0]
    given = (f"with the cloud its reflectance implies ({head['dataset']}: tau "
             f"{c['optical_depth']:g}{_on_signal(head)}), on cloudy segments")
    judged = {}
    for name, mk, ak, agrees in QUANTITIES:
        if name == "signal" and head["circular"]:
            given += f" (signal not compared: {head['dataset']} is made from it)"
            continue
        j = judge([a[ak] for a in alts], m[mk], agrees)
        if j is not None:
            judged[name] = j
    if not judged:           # (no background rate, and the signal not compared or absent)
        return "not measured", given + ": nothing to compare (the file gives no background " \
            "rate here" + ("" if head["circular"] else ", nor a signal rate") + ")"
    failing = {k: j for k, j in judged.items() if not j["agrees"]}
    if not failing:
        return "agrees", given + ": " + ", ".join(f"{k} x{j['ratio']:.2f}"
                                                  for k, j in judged.items()) + _also(judged)
    if any(not j["reaches"] for j in failing.values()) or \
            not all(j["wide"] for j in failing.values()):
        return "disagrees", given + ": " + ", ".join(
            f"{k} x{j['ratio']:.2f}" for k, j in failing.items()) + _also(judged)
    return "cloud uncertain", _uncertain(row, alts, judged)


def _given(bg, sig) -> tuple[str, str]:
    given = "with the cloud given, on cloudy segments"
    bad = [f"{k} x{v:.2f}" for k, v, (lo, hi) in (("background", bg, BACKGROUND_AGREES),
                                                  ("signal", sig, SIGNAL_AGREES))
           if v is not None and not lo <= v <= hi]
    if bad:
        return "disagrees", f"{given}: " + ", ".join(bad)
    if bg is None and sig is None:
        return "not measured", f"{given}: the file gives neither a background nor a signal rate"
    return "agrees", f"{given}: background x{_fmt(bg)}, signal x{_fmt(sig)}"


def _on_signal(a: dict) -> str:
    """``", 0.78 on the segments that measure the signal"`` where that depth differs."""
    t = a.get("signal_optical_depth")
    return "" if t is None or t == a["optical_depth"] else \
        f", {t:g} on the segments that measure the signal"


def _also(judged: dict) -> str:
    """The brackets of the quantities whose file's clouds spread wider than the verdict
    tells apart (said beside an agreeing or disagreeing verdict)."""
    wide = [f"{k} x{j['lo']:.2f}-{j['hi']:.2f}" for k, j in judged.items() if j["wide"]]
    return "" if not wide else "; over the clouds the file allows " + ", ".join(wide)


def _uncertain(row: dict, alts: list, judged: dict) -> str:
    """The reason of a *cloud uncertain* verdict: what the file's inputs say of the cloud and
    the bracket of each quantity they give."""
    head = alts[0]
    taus = {}
    for a in alts:
        taus.setdefault(a["dataset"], a)
    said = [f"{k} ({a['from']}{'; circular for the signal' if a['circular'] else ''}) tau "
            f"{a['optical_depth']:g}{_on_signal(a)}" for k, a in taus.items()]
    why = ("the file's reflectances disagree on the cloud: " + ", ".join(said)
           + " (each against snow's 0.9: no clear segment gives its own clear reading)")
    if len(taus) == 1:
        why = "the cloud's " + said[0]
    above = [a for a in alts if a["above_band"]]
    if above and above[0].get("height_unknown"):
        why += (f"; the file places no layer (no msw_flag on these segments): the cloud taken "
                f"at {head['base_m']:g}-{head['top_m']:g} m, inside the band, and above it "
                f"from {above[0]['base_m']:g} m")
    elif above:
        layers = {"ATL06": "cloud_flg_atm", "ATL07": "cloud_flag_atm"}.get(row["product"],
                                                                           "the layer flag")
        why += (f"; ATL09 found several layers ({layers}) where msw_flag places only the "
                f"lowest ({head['base_m']:g}-{head['top_m']:g} m, inside the band up to "
                f"{above[0]['base_m']:g} m): the depth's split between them, inside the band "
                "and above it, is not in the file")
    m = row["measured"]
    meas = {"background": f"{m['background_cloudy_hz'] / 1e3:.3g} kHz"
            if m["background_cloudy_hz"] else "-",
            "signal": f"{m['signal_cloudy']:.2f}" if m["signal_cloudy"] else "-"}
    rng = [f"{k} x{j['lo']:.2f}-{j['hi']:.2f} of {meas[k]} (x{j['ratio']:.2f} with "
           f"{head['dataset']}'s cloud{' in the lowest layer' if above else ''})"
           for k, j in judged.items()]
    return f"cloud uncertain: {why}; " + ", ".join(rng)
