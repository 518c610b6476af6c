#!/usr/bin/env python3
"""m and c from two runs that differ only in the sign of their one shear.

    python3 tests/analysis/paired_shear.py RUN_PLUS CAT_PLUS RUN_MINUS CAT_MINUS

Each run has one dataset (`shears` = [{g1: +g, g2: 0}] and [{g1: -g, g2:
0}], or with g2 = g1 likewise) and the same `run.seed`, so the two hold the same galaxies at the same
positions and, as an image's noise is keyed by its dataset index, the same
pixel noise: what differs is the shear alone, and shape noise and most
pixel noise cancel in the difference. Each catalogue row is matched to the
nearest truth galaxy within 1 arcsec, one row per galaxy (the grid's lists
of tests/analysis/isolated_grid.py place no neighbour within 13 arcsec).
Per base field (its rotated twin pooled with it):

    m = (<e1>+ - <e1>-) / (g+ - g-) - 1,   c1 = (<e1>+ + <e1>-) / 2,
    c2 = (<e2>+ + <e2>-) / 2,
    m2 = (<e2>+ - <e2>-) / (g2+ - g2-) - 1 (where the runs' g2 differ),

with <.> the weighted mean over the field's kept rows (weight > 0); mean
+- standard error over the fields (both runs must hold the same fields).
m is split, on the same rows, into the selection (the same difference of
the weighted mean intrinsic e1_int) and the estimator (of e1 - e1_int);
they add up to m. "c2, selection" is the weighted mean intrinsic e2_int
of the kept rows, pooled the same way: what the cuts leave of the
population's own e2. For metacalibration the split is not the method's
own (its rows carry the dataset's response, larger galaxies read high and
smaller ones low), m is; and the per-field errors do not see the error of
that response, which all fields share. The same is printed for the rows
of true magnitude 17-22, 22-23 and 23-24. Printed before them: the
fraction of the truth's galaxies found in each run (a row matched,
weighted or not; over the images that have rows, every magnitude) and
the selection of finding them, the slope of their mean e1_int: the
detection's, which metacalibration's R_S does not see.

Needs numpy, scipy and astropy; not run by CI.
"""
import sys

import numpy as np

from selection_slopes import galaxy_matches, read_catalogue


def matched(run, catalogue):
    """(field, g1, e1_int, e1, e2, weight, mag, e2_int, g2) of each matched
    galaxy row; (field, e1_int, found) of every galaxy of the run's truth
    files, found when a row, weighted or not, is matched to it; and the
    number of weighted rows matched to no galaxy."""
    rows = read_catalogue(catalogue)
    out = []
    every = []
    unmatched = 0
    for key, t, c, g, lost in galaxy_matches(run, rows, one_per_galaxy=True):
        unmatched += lost
        n = len(g)
        out.append(np.column_stack([
            np.full(n, int(key("FIELD"))), np.full(n, key("G1")), t["e1_int"][g],
            c[:, 2], c[:, 3], c[:, 4], t["mag"][g], t["e2_int"][g],
            np.full(n, key("G2"))]))
        gal = np.nonzero(t["kind"] == 1)[0]
        every.append(np.column_stack([
            np.full(len(gal), int(key("FIELD"))), t["e1_int"][gal], np.isin(gal, g)]))
    if not out:
        sys.exit(f"{catalogue}: no row matched a galaxy of {run}")
    return np.concatenate(out), np.concatenate(every), unmatched


def found_line(p, m, gp, gm):
    """The galaxies found (a row matched, weighted or not) in each run and
    the selection of finding them: the slope of their mean e1_int, per
    base field, mean +- standard error over the fields."""
    v = []
    for f in np.unique(p[:, 0]):
        fp = p[(p[:, 0] == f) & (p[:, 2] > 0)]
        fm = m[(m[:, 0] == f) & (m[:, 2] > 0)]
        if len(fp) and len(fm):
            v.append((fp[:, 1].mean() - fm[:, 1].mean()) / (gp - gm))
    if not v:
        print("galaxies found: no base field has a galaxy found in both runs")
        return
    v = np.array(v)
    err = v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else float("nan")
    print(f"galaxies found (a row, weighted or not): {p[:, 2].mean():.4f} / "
          f"{m[:, 2].mean():.4f} of {len(p)} / {len(m)}; "
          f"their selection {v.mean():+.4f} ± {err:.4f}")


def field_means(a, value):
    """{field: weighted mean of value over its kept rows}."""
    out = {}
    for f in np.unique(a[:, 0]):
        s = (a[:, 0] == f) & (a[:, 5] > 0)
        if s.any():
            out[f] = np.average(value[s], weights=a[s, 5])
    return out


COLUMNS = {
    # name: (value of a row, slope (True) or mean (False), minus 1)
    "m": (lambda a: a[:, 3], True, True),
    "selection": (lambda a: a[:, 2], True, False),
    "estimator": (lambda a: a[:, 3] - a[:, 2], True, True),
    "m2": (lambda a: a[:, 4], "g2", True),
    "c1": (lambda a: a[:, 3], False, False),
    "c2": (lambda a: a[:, 4], False, False),
    "c2, selection": (lambda a: a[:, 7], False, False),
}


def paired(p, m, gp, gm, name):
    parts = [f"{name:16s}{int((p[:, 5] > 0).sum()):8d}{int((m[:, 5] > 0).sum()):8d}"]
    for value, slope, minus_one in COLUMNS.values():
        fp, fm = field_means(p, value(p)), field_means(m, value(m))
        fields = sorted(set(fp) & set(fm))
        if not fields:
            parts.append(f"{'-':>19s}")
            continue
        if slope == "g2":
            # m2 only where the runs' g2 differ (g1 = g2 = +-g designs).
            dg2 = p[0, 8] - m[0, 8]
            if dg2 == 0:
                parts.append(f"{'-':>19s}")
                continue
            v = np.array([(fp[f] - fm[f]) / dg2 for f in fields]) - float(minus_one)
        elif slope:
            v = np.array([(fp[f] - fm[f]) / (gp - gm) for f in fields]) - float(minus_one)
        else:
            v = np.array([(fp[f] + fm[f]) / 2 for f in fields])
        err = v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else float("nan")
        fmt = "{:+.4f} ± {:.4f}" if slope else "{:+.5f} ± {:.5f}"
        parts.append(f" {fmt.format(v.mean(), err):>18s}")
    print("".join(parts))


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    p, every_p, up = matched(sys.argv[1], sys.argv[2])
    m, every_m, um = matched(sys.argv[3], sys.argv[4])
    for a, run in [(p, sys.argv[1]), (m, sys.argv[3])]:
        if len(np.unique(a[:, 1])) != 1 or len(np.unique(a[:, 8])) != 1:
            sys.exit(f"{run}: the run must have one shear")
    gp, gm = p[0, 1], m[0, 1]
    if not (gp > 0 and gm == -gp and p[0, 8] == -m[0, 8]):
        sys.exit(f"g = ({gp:+g}, {p[0, 8]:+g}) and ({gm:+g}, {m[0, 8]:+g}): the first run must "
                 "have +g, the second -g")
    fields_p, fields_m = set(np.unique(p[:, 0])), set(np.unique(m[:, 0]))
    if fields_p != fields_m:
        sys.exit(f"the runs hold different base fields: {sorted(fields_p ^ fields_m)} in one only")
    print(f"g1 = {gp:+g} / {gm:+g}; {len(fields_p)} base fields; "
          f"weighted rows matched to no galaxy: {up} / {um}")
    found_line(every_p, every_m, gp, gm)
    print(f"{'rows':16s}{'kept +':>8s}{'kept -':>8s}"
          + "".join(f" {h:>18s}" for h in COLUMNS))
    paired(p, m, gp, gm, "all")
    for lo, hi in [(17, 22), (22, 23), (23, 24)]:
        paired(p[(p[:, 6] >= lo) & (p[:, 6] < hi)], m[(m[:, 6] >= lo) & (m[:, 6] < hi)],
               gp, gm, f"I {lo}-{hi}")


if __name__ == "__main__":
    main()
