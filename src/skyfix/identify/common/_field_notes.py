"""What a failed search says about the field (:mod:`skyfix.identify.methods.quad`'s failure
notes): a FOV no database serves, with the commands that build one that does, and a field too
narrow for the bundled catalogue."""

from __future__ import annotations

import math

from skyfix.identify.catalogue.bands import served_fov_deg, served_range_deg
from skyfix.validate import FOV_RANGE_DEG


def _outside_reason(fov: float | None, fov_lo: float | None, fov_hi: float | None, sources: list) -> str:
    """The failure reason for a FOV (allowed ``fov_lo``–``fov_hi``) no database can serve (the
    database given, or every default band when ``sources`` is empty), with the commands that
    build and use one that can: below the default bands, from a deeper catalogue (the bundled
    ones hold too few stars in so narrow a field)."""
    lo_band, hi_band = served_range_deg()
    narrow = fov_hi < lo_band
    if narrow:  # two significant digits: 0.5–0.75°, not 0–1°
        lo = max(FOV_RANGE_DEG[0], float(f"{fov_lo:.2g}"))
        hi = min(FOV_RANGE_DEG[1], max(lo, float(f"{fov_hi:.2g}")))
    else:
        lo = max(FOV_RANGE_DEG[0], math.floor(fov_lo + 1e-9))
        hi = min(FOV_RANGE_DEG[1], math.ceil(fov_hi - 1e-9))
    out = f"patterns-{lo:g}-{hi:g}deg.npz"
    if sources:
        db = sources[0]
        served = served_fov_deg(db)
        what = (f"the pattern database's range {db.fov_min_deg:g}–{db.fov_max_deg:g}° (it serves "
                f"{served[0]:.3g}–{served[1]:.3g}°)")
    else:
        what = f"every default FOV band (they serve {lo_band:.3g}–{hi_band:.3g}°)"
    if narrow:
        n_stars = shallow_field_stars(fov)
        return (f"field of view {fov:.3g}° is outside {what}: a field this narrow holds about "
                f"{n_stars:.0f} stars of the bundled catalogue (Gaia to G 10), too few to identify; "
                f"build a database from a deeper catalogue file (docs/catalogues.md#a-deeper-catalogue): "
                f"`skyfix database build --fov-min {lo:g} --fov-max {hi:g} --catalog DEEP.csv -o {out}`, "
                f"then `skyfix solve --database {out} ...`")
    return (f"field of view {fov:.3g}° is outside {what}; build one that covers it: "
            f"`skyfix database build --fov-min {lo:g} --fov-max {hi:g} -o {out}`, "
            f"then `skyfix solve --database {out} ...`")


#: Stars a square degree of the bundled Gaia catalogue holds on average (G ≤ 10; 4.4–5.1 at the
#: galactic poles: docs/catalogues.md).
GAIA_STARS_PER_SQ_DEG = 11.7


def shallow_field_stars(fov_deg: float, aspect: float = 0.75) -> float:
    """The bundled catalogue's stars in a ``fov_deg``-wide frame of ``aspect`` (height/width), on average."""
    return GAIA_STARS_PER_SQ_DEG * fov_deg * fov_deg * aspect


def _shallow_note(fov_hi: float | None) -> str:
    """What a failed search adds when the frame (at most ``fov_hi`` wide, when known) holds on
    average fewer than twice the 8 catalogue stars a solve needs: the catalogue may be too shallow."""
    if fov_hi is None or shallow_field_stars(fov_hi) >= 16.0:
        return ""
    return (f"; a {fov_hi:.2g}° field holds about {shallow_field_stars(fov_hi):.0f} stars of the bundled "
            f"catalogue (Gaia to G 10) on average, fewer in sparse parts of the sky: if the frame shows "
            f"fewer than 8 of them, solve it with a database built from a deeper catalogue "
            f"(docs/catalogues.md#a-deeper-catalogue)")
