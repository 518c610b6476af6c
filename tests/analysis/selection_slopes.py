#!/usr/bin/env python3
"""Which of KSB+'s cuts select on the shear, on isolated galaxies.

    python3 tests/analysis/selection_slopes.py RUN CATALOGUE

RUN is a run directory (its `private/truth/*.fits`), CATALOGUE what
`stepsim measure` wrote for RUN/public (`image x y e1 e2 weight flags`).
Each catalogue row is matched to the nearest truth galaxy with I < 24
within 1 arcsec (one row per galaxy, nearest first); only galaxies that
are isolated as the harness classes them are kept (no other object with
at least 10 % of their flux within 3 arcsec). For a subset of those rows
(every matched galaxy; those one flag would keep; those all flags keep;
all flags but one), the selection slope is the slope of the mean
*intrinsic* e1 (truth `e1_int`) of the subset against the dataset's g1,
fitted per base field over its shears; printed is the mean over base
fields +- its standard error. A selection that does not depend on the
shear has slope 0; a slope s adds s to m. The last lines give the
estimator's own bias on the kept rows, paired: the slope of the weighted
mean of (e1 - e1_int) against g1, minus 1.

Measured numbers: docs/baseline.md, "Which cuts select on the shear".
Needs numpy, scipy and astropy; not run by CI.
"""
import glob
import sys

import numpy as np
from astropy.io import fits
from scipy.spatial import cKDTree

PIXEL_SCALE = 0.206
FLAGS = {"EDGE": 1, "SATURATED": 2, "BLENDED": 4, "CENTROID": 8, "MOMENTS": 16,
         "SMALL": 32, "LARGE": 64, "LOW_SN": 128, "PGAMMA": 256, "BIG_SHEAR": 512,
         "NO_PSF": 1024, "SHIFTED": 2048}


def read_catalogue(path):
    rows = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        w = line.split()
        rows.setdefault(w[0], []).append([float(v) for v in w[1:6]] + [int(w[6])])
    return rows


def truth_tables(run, rows):
    """(image, key, table) of each truth file of RUN whose image has rows;
    key(k) is the first header value of keyword k."""
    for path in sorted(glob.glob(f"{run}/private/truth/*.fits")):
        image = path.split("/")[-1][: -len(".fits")]
        if image not in rows:
            continue
        hdus = fits.open(path)
        yield image, lambda k, h=hdus: next(x.header[k] for x in h if k in x.header), hdus[1].data


def galaxy_matches(run, rows, one_per_galaxy=False):
    """(key, table, matched rows, their galaxies' indices, weighted rows
    matched to none) of each truth file of RUN whose image has rows: each
    row matched to the nearest truth galaxy within 1 arcsec (with
    one_per_galaxy, only a galaxy's nearest row is kept)."""
    for image, key, t in truth_tables(run, rows):
        c = np.array(rows[image])
        gal = np.nonzero(t["kind"] == 1)[0]
        tree = cKDTree(np.column_stack([t["x"][gal], t["y"][gal]]))
        d, k = tree.query(c[:, :2], distance_upper_bound=1.0 / PIXEL_SCALE)
        ok = np.isfinite(d)
        unmatched = int((~ok & (c[:, 4] > 0)).sum())
        r = np.nonzero(ok)[0]
        if one_per_galaxy:
            r = r[np.argsort(d[r], kind="stable")]
            r = r[np.unique(k[r], return_index=True)[1]]
        yield key, t, c[r], gal[k[r]], unmatched


def matched_isolated(run, rows):
    """(field, g1, e1_int, e1, weight, flags) of each matched isolated galaxy."""
    out = []
    for image, key, t in truth_tables(run, rows):
        field = 2 * int(key("FIELD")) + int(key("ROTATED"))
        xy = np.column_stack([t["x"], t["y"]])
        flux = t["flux_e"]
        pairs = cKDTree(xy).query_pairs(3.0 / PIXEL_SCALE, output_type="ndarray")
        isolated = np.ones(len(t), bool)
        i, j = pairs[:, 0], pairs[:, 1]
        isolated[i[flux[j] >= 0.1 * flux[i]]] = False
        isolated[j[flux[i] >= 0.1 * flux[j]]] = False
        galaxies = np.nonzero((t["kind"] == 1) & (t["mag"] < 24.0))[0]
        c = np.array(rows[image])
        d, k = cKDTree(xy[galaxies]).query(c[:, :2], distance_upper_bound=1.0 / PIXEL_SCALE)
        taken = set()
        for r in np.argsort(d):
            if not np.isfinite(d[r]) or galaxies[k[r]] in taken:
                continue
            g = galaxies[k[r]]
            taken.add(g)
            if isolated[g]:
                out.append((field, key("G1"), t["e1_int"][g], c[r, 2], c[r, 4], int(c[r, 5])))
    return np.array(out, dtype=float)


def main():
    run, catalogue = sys.argv[1], sys.argv[2]
    a = matched_isolated(run, read_catalogue(catalogue))
    field, g1, e1_int, e1, weight, flags = a.T
    flags = flags.astype(int)
    shears = sorted(set(g1))
    fields = sorted(set(field))
    print(f"{run}: {len(a)} rows matched to isolated I < 24 galaxies, "
          f"{len(fields)} base fields, shears {[float(g) for g in shears]}")

    def slope(keep, value):
        per_field = []
        for f in fields:
            xs, ys = [], []
            for g in shears:
                m = keep & (field == f) & (g1 == g)
                if m.sum() >= 5:
                    xs.append(g)
                    ys.append(np.sum(weight[m] * value[m]) / np.sum(weight[m]))
            if len(xs) >= 3:
                per_field.append(np.polyfit(xs, ys, 1)[0])
        s = np.array(per_field)
        return s.mean(), s.std(ddof=1) / np.sqrt(len(s))

    def line(name, keep, value=e1_int, minus=0.0):
        m, e = slope(keep, value)
        print(f"{name:44s} {m - minus:+.4f} ± {e:.4f}   rows {int(keep.sum()):7d}")

    # Selection slopes weight every row alike (a cut keeps or drops it).
    weight_kept = weight.copy()
    weight[:] = 1.0
    line("every matched galaxy (detection, matching)", np.ones(len(a), bool))
    present = [(n, b) for n, b in FLAGS.items() if (flags & b).any()]
    for name, bit in present:
        line(f"only the {name} cut", (flags & bit) == 0)
    line("all cuts (flags = 0)", flags == 0)
    for name, bit in present:
        line(f"all cuts but {name}", (flags & ~bit) == 0)
    weight[:] = weight_kept
    kept = flags == 0
    line("m of the kept rows (weighted e1 slope − 1)", kept, e1, 1.0)
    line("estimator: weighted (e1 − e1_int) slope − 1", kept, e1 - e1_int, 1.0)


if __name__ == "__main__":
    main()
