#!/usr/bin/env python3
"""Metacal's m on subsets of the truth, each subset with its own response.

    python3 tests/analysis/metacal_subsets.py RUN DETAILS

RUN is a run directory (its `private/truth/*.fits`), DETAILS the table
`stepsim measure --method metacal --details DETAILS` wrote for RUN/public
(docs/ksb.md, "The details table": the five versions' e and the mask of
the versions that pass the cuts). Each row whose versions were made is
matched to the nearest truth object within 1 arcsec and classed: matched
to a galaxy (isolated as the harness classes it: no other object with at
least 10 % of its flux within 3 arcsec; by magnitude), to a star, or to
nothing; and by the distance to the nearest true star. For each class
the response R = R_gamma + R_S (docs/metacal.md step 7) is computed per
dataset from the class's rows alone, the shear estimate of a base field
(twins pooled) and dataset is R^-1 <e(0)> over its rows selected
unsheared, and m per base field is the mean over the two components of
the slope of that estimate on the dataset's g, minus 1. Printed: mean m
over base fields +- its standard error, the rows selected unsheared and
the mean of R's diagonal.

Measured numbers: docs/metacal.md, "Where the lensed scene's bias sits".
Needs numpy, scipy and astropy; not run by CI.
"""
import sys

import numpy as np
from scipy.spatial import cKDTree

from noise_bias import read_details
from selection_slopes import PIXEL_SCALE, truth_tables


def isolated(xy, flux, galaxy, a):
    """Which objects have no other with at least 10 % of their flux within
    3 arcsec. Between two galaxies the separation is taken in the source
    plane (A applied to the image's, SPEC section 1; the factor
    (1 - |g|^2)^(-1/2) is left out), so that the class does not depend on
    the shear: in the image plane a pair stretched along the shear is
    classed isolated more often, which selects on the shear. Stars are not
    lensed, and a galaxy's separation from a star is the image's."""
    iso = np.ones(len(xy), bool)
    radius = 3.0 / PIXEL_SCALE
    for plane, both in [(xy, lambda i, j: ~(galaxy[i] & galaxy[j])),
                        (xy @ a.T, lambda i, j: galaxy[i] & galaxy[j])]:
        pairs = cKDTree(plane).query_pairs(radius, output_type="ndarray")
        i, j = pairs[:, 0], pairs[:, 1]
        keep = both(i, j)
        i, j = i[keep], j[keep]
        iso[i[flux[j] >= 0.1 * flux[i]]] = False
        iso[j[flux[i] >= 0.1 * flux[j]]] = False
    return iso


def classed_rows(run, rows):
    """Arrays over the rows whose versions were made: field, g (n x 2),
    versions' e (n x 5 x 2), mask, and a dict of class -> boolean array."""
    field, g, e, mask = [], [], [], []
    cls = {}
    for image, key, t in truth_tables(run, rows):
        c = np.array(rows[image])
        c = c[np.isfinite(c[:, 14])]
        xy = np.column_stack([t["x"], t["y"]])
        flux = t["flux_e"]
        g1, g2 = float(key("G1")), float(key("G2"))
        iso = isolated(xy, flux, t["kind"] == 1, np.array([[1 - g1, -g2], [-g2, 1 + g1]]))
        d, k = cKDTree(xy).query(c[:, :2], distance_upper_bound=1.0 / PIXEL_SCALE)
        found = np.isfinite(d)
        k = np.where(found, k, 0)
        star = t["kind"] == 0
        star_d, _ = cKDTree(xy[star]).query(c[:, :2])
        gal = found & (t["kind"][k] == 1)
        mag = t["mag"][k]
        these = {
            "all rows": np.ones(len(c), bool),
            "matched to a galaxy": gal,
            "matched to a star": found & (t["kind"][k] == 0),
            "matched to nothing": ~found,
            "galaxy, isolated": gal & iso[k],
            "galaxy, not isolated": gal & ~iso[k],
            "galaxy I < 24, isolated": gal & iso[k] & (mag < 24),
            "galaxy I < 24, not isolated": gal & ~iso[k] & (mag < 24),
            "galaxy I >= 24, isolated": gal & iso[k] & (mag >= 24),
            "galaxy I >= 24, not isolated": gal & ~iso[k] & (mag >= 24),
        }
        for lo, hi in [(0, 22), (22, 23), (23, 24), (24, 25), (25, 99)]:
            these[f"galaxy, {lo} <= I < {hi}"] = gal & (mag >= lo) & (mag < hi)
        these["a star within 15 px"] = star_d < 15
        these["no star within 15 px"] = star_d >= 15
        for name, sel in these.items():
            cls.setdefault(name, []).append(sel)
        field.append(np.full(len(c), int(key("FIELD"))))
        g.append(np.tile([float(key("G1")), float(key("G2"))], (len(c), 1)))
        e.append(c[:, 14:24].reshape(-1, 5, 2))
        mask.append(c[:, 24].astype(int))
    cat = np.concatenate
    return cat(field), cat(g), cat(e), cat(mask), {n: cat(v) for n, v in cls.items()}


def response(e, mask):
    """R = R_gamma + R_S of the rows e (n x 5 x 2) with masks `mask`."""
    on = lambda v: (mask >> v) & 1 == 1
    r = np.zeros((2, 2))
    for j in range(2):
        p, m = 1 + 2 * j, 2 + 2 * j
        r_gamma = ((e[on(0), p] - e[on(0), m]) / 0.02).mean(0)
        r_sel = (e[on(p), 0].mean(0) - e[on(m), 0].mean(0)) / 0.02
        r[:, j] = r_gamma + r_sel
    return r


def subset_m(field, g, e, mask, sel):
    shears = sorted({tuple(x) for x in g[sel]})
    resp = {s: response(e[sel & (g == s).all(1)], mask[sel & (g == s).all(1)]) for s in shears}
    ms = []
    for f in sorted(set(field[sel])):
        gs, est = [], []
        for s in shears:
            k = sel & (field == f) & (g == s).all(1) & (mask & 1 == 1)
            if k.sum() >= 3:
                gs.append(s)
                est.append(np.linalg.solve(resp[s], e[k, 0].mean(0)))
        if len(gs) >= 3:
            gs, est = np.array(gs), np.array(est)
            ms.append(np.mean([np.polyfit(gs[:, a], est[:, a], 1)[0] - 1 for a in range(2)]))
    ms = np.array(ms)
    r_diag = np.mean([np.trace(r) / 2 for r in resp.values()])
    return ms.mean(), ms.std(ddof=1) / np.sqrt(len(ms)), len(ms), int((sel & (mask & 1 == 1)).sum()), r_diag


def main():
    run, path = sys.argv[1], sys.argv[2]
    field, g, e, mask, cls = classed_rows(run, read_details(path))
    for name, sel in cls.items():
        m, err, nf, n0, r = subset_m(field, g, e, mask, sel)
        print(f"{name:30s} selected {n0:7d}  <R_ii> {r:.3f}  m {m:+.4f} ± {err:.4f}  ({nf} fields)")


if __name__ == "__main__":
    main()
