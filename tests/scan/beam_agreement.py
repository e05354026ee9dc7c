"""Compare two simulated clouds pulse by pulse (adaptive against full beam sampling)."""

from __future__ import annotations

import numpy as np


def pulse_key(cloud) -> np.ndarray:
    f = cloud.fields
    return (
        f["station"].astype(np.int64) << 50
        | f["scan_column"].astype(np.int64) << 25
        | f["scan_line"].astype(np.int64)
    )


def agreement(a, b) -> dict[str, float]:
    """Figures of how cloud ``a`` departs from cloud ``b`` (per pulse, per return).

    ``pulses``: pulses with a return in either; ``same_count``: the fraction of them with
    the same number of returns; ``range_max_m``/``position_max_m``: the largest range and
    position difference between returns of those pulses, matched by return number;
    ``intensity_max``: the largest intensity difference (counts of 65535);
    ``range_within_0.1mm``, ``intensity_same``: fractions of those returns whose range is
    within 0.1 mm, whose intensity is identical, within 8 counts;
    ``returns_a``/``returns_b``: the returns in each.
    """
    ka, kb = pulse_key(a), pulse_key(b)
    ua, ca = np.unique(ka, return_counts=True)
    ub, cb = np.unique(kb, return_counts=True)
    keys = np.union1d(ua, ub)
    na = np.zeros(len(keys), np.int64)
    nb = np.zeros(len(keys), np.int64)
    na[np.searchsorted(keys, ua)] = ca
    nb[np.searchsorted(keys, ub)] = cb
    same = keys[na == nb]
    ia, ib = np.isin(ka, same), np.isin(kb, same)
    oa = np.lexsort((a.fields["return_number"][ia], ka[ia]))
    ob = np.lexsort((b.fields["return_number"][ib], kb[ib]))
    ra = a.fields["range_m"][ia][oa]
    rb = b.fields["range_m"][ib][ob]
    pa, pb = a.points[ia][oa], b.points[ib][ob]
    inta = a.fields["intensity"][ia][oa].astype(np.int64)
    intb = b.fields["intensity"][ib][ob].astype(np.int64)
    dr = np.abs(ra - rb)
    return {
        "range_within_0.1mm": float((dr <= 1e-4).mean()) if len(dr) else 1.0,
        "intensity_same": float((inta == intb).mean()) if len(inta) else 1.0,
        "intensity_within_8": float((np.abs(inta - intb) <= 8).mean()) if len(inta) else 1.0,
        "pulses": float(len(keys)),
        "same_count": float((na == nb).mean()) if len(keys) else 1.0,
        "range_max_m": float(np.abs(ra - rb).max()) if len(ra) else 0.0,
        "position_max_m": float(np.linalg.norm(pa - pb, axis=1).max()) if len(pa) else 0.0,
        "intensity_max": float(np.abs(inta - intb).max()) if len(inta) else 0.0,
        "returns_a": float(len(ka)),
        "returns_b": float(len(kb)),
    }
