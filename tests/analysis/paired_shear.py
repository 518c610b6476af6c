#!/usr/bin/env python3
"""m and c from two runs that differ only in the sign of their one shear.

    python3 tests/analysis/paired_shear.py RUN_PLUS CAT_PLUS RUN_MINUS CAT_MINUS

Each run has one dataset (`shears` = [{g1: +g}] and [{g1: -g}]) and the same
`run.seed`, so the two hold the same galaxies at the same positions and, as
an image's noise is keyed by its dataset index, the same noise: what differs
is the shear alone, and shape noise and most pixel noise cancel in the
difference. Rows are matched to truth galaxies within 1 arcsec (the grid's
lists of tests/analysis/isolated_grid.py place no neighbour within 13
arcsec). Per base field (its rotated twin pooled with it):

    m = (<e1>+ - <e1>-) / (g+ - g-) - 1,   c1 = (<e1>+ + <e1>-) / 2,
    c2 = (<e2>+ + <e2>-) / 2,

with <.> the weighted mean over the field's kept rows (weight > 0); mean
+- standard error over the fields. m is split, on the same rows, into the
selection (the same difference of the weighted mean intrinsic e1_int) and
the estimator (of e1 - e1_int); they add up to m. For metacalibration the
split is not the method's own (its rows carry the dataset's response), m
is. Also printed by magnitude.

Needs numpy, scipy and astropy; not run by CI.
"""
import sys

import numpy as np
from scipy.spatial import cKDTree

from selection_slopes import PIXEL_SCALE, read_catalogue, truth_tables


def matched(run, catalogue):
    """(field, g1, e1_int, e1, e2, weight, mag, e2_int) of each matched galaxy
    row."""
    rows = read_catalogue(catalogue)
    out = []
    for image, key, t in truth_tables(run, rows):
        field = int(key("FIELD"))
        xy = np.column_stack([t["x"], t["y"]])
        galaxies = np.nonzero(t["kind"] == 1)[0]
        c = np.array(rows[image])
        d, k = cKDTree(xy[galaxies]).query(c[:, :2], distance_upper_bound=1.0 / PIXEL_SCALE)
        ok = np.isfinite(d)
        g = galaxies[k[ok]]
        c = c[ok]
        n = len(g)
        out.append(np.column_stack([
            np.full(n, field), np.full(n, key("G1")), t["e1_int"][g],
            c[:, 2], c[:, 3], c[:, 4], t["mag"][g], t["e2_int"][g]]))
    return np.concatenate(out)


def field_means(a, value):
    """{field: weighted mean of value over its kept rows}."""
    out = {}
    for f in np.unique(a[:, 0]):
        s = (a[:, 0] == f) & (a[:, 5] > 0)
        if s.any():
            out[f] = np.average(value[s], weights=a[s, 5])
    return out


def paired(p, m, name, keep_p, keep_m):
    p, m = p[keep_p], m[keep_m]
    gp, gm = p[0, 1], m[0, 1]
    cols = {
        "m": (lambda a: a[:, 3], True),
        "selection": (lambda a: a[:, 2], True),
        "estimator": (lambda a: a[:, 3] - a[:, 2], True),
        "c1": (lambda a: a[:, 3], False),
        "c2": (lambda a: a[:, 4], False),
        "c2, selection": (lambda a: a[:, 7], False),
    }
    parts = [f"{name:16s}{int((p[:, 5] > 0).sum()):8d}{int((m[:, 5] > 0).sum()):8d}"]
    for col, (value, slope) in cols.items():
        fp, fm = field_means(p, value(p)), field_means(m, value(m))
        fields = sorted(set(fp) & set(fm))
        if slope:
            v = np.array([(fp[f] - fm[f]) / (gp - gm) for f in fields])
            v -= 1.0 if col in ("m", "estimator") else 0.0
        else:
            v = np.array([(fp[f] + fm[f]) / 2 for f in fields])
        err = v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else float("nan")
        fmt = "{:+.4f} ± {:.4f}" if slope else "{:+.5f} ± {:.5f}"
        parts.append(f"{fmt.format(v.mean(), err):>18s}")
    print("".join(parts))


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    p = matched(sys.argv[1], sys.argv[2])
    m = matched(sys.argv[3], sys.argv[4])
    if not (p[0, 1] > 0 > m[0, 1]):
        sys.exit("the first run must have the positive g1, the second the negative")
    print(f"g1 = {p[0, 1]:+g} / {m[0, 1]:+g}; {len(np.unique(p[:, 0]))} base fields")
    print(f"{'rows':16s}{'kept +':>8s}{'kept -':>8s}" + "".join(
        f"{h:>18s}" for h in ["m", "selection", "estimator", "c1", "c2", "c2, selection"]))
    paired(p, m, "all", slice(None), slice(None))
    for lo, hi in [(17, 22), (22, 23), (23, 24)]:
        paired(p, m, f"I {lo}-{hi}", (p[:, 6] >= lo) & (p[:, 6] < hi),
               (m[:, 6] >= lo) & (m[:, 6] < hi))


if __name__ == "__main__":
    main()
