#!/usr/bin/env python3
"""KSB+ on isolated galaxies: the preset's galaxies on a grid, no neighbours.

    python3 tests/analysis/isolated_grid.py lists CATALOG_DIR OUT_DIR N_FIELDS [turned]
    python3 tests/analysis/isolated_grid.py table RUN CATALOGUE [c]

`lists` reads the SkyMaker lists `stepsim catalog` wrote (CATALOG_DIR/
field_kkk.list) and writes OUT_DIR/f{k}.list for k < N_FIELDS: every cell
of a 64 px grid over a 4096² image (4096 cells, 13.2 arcsec apart) holds one
object at the cell's centre plus a uniform sub-pixel offset; 800 cells hold
stars of 18.5 < I < 21 drawn from the field's own (with replacement; with
200 the stellar locus was not found among 3 900 bright galaxies), the rest
the field's galaxies with I < 24 in a random order (3 296 of about 7 700).
With `turned` the grid is turned by atan(1/2) = 26.57 degrees about the
image's centre (the same 64 px spacing; 3 977 cells at least 32 px from the
edges, so 3 177 galaxies): its nearest cells along a pixel row or column
are 143 px apart instead of 64, and along a diagonal 202 px instead of 91.
The preset's optical PSFs have diffraction spikes along the pixels' axes
that reach beyond metadetection's PSF stack (31.5 px), and on the plain
grid each galaxy lies on the spikes of its four nearest neighbours: they
are not deconvolved, and their response to the versions' shear is not a
galaxy's (docs/metacal.md, "The spikes of the grid's neighbours").
Seeds are fixed (1000 + k), so the lists are the same on every run. A config
with `population.source = {"skymaker_list": {"path": "OUT_DIR/f{field}.list"}}`
and `population.rotated_pairs = true` renders them (docs/baseline.md,
"Isolated galaxies on a grid").

`table` matches each catalogue row (`image x y e1 e2 weight flags`) to the
truth galaxy within 1 arcsec and prints, for all rows and by size and
magnitude bins, three slopes against g1 fitted per base field over its
shears (the rotated twin pooled with its field, so shape noise cancels),
mean +- standard error over fields: m of the kept rows (weighted mean e1,
minus 1), the selection (weighted mean of the true intrinsic e1_int of the
kept rows: what the cuts and the weights add to m) and the estimator
(weighted mean of e1 - e1_int, minus 1: the bias on the same rows, paired);
the two add up to m. With `c` it prints the
intercepts instead (c1 and its two parts). Size bins are by a crude
half-light radius, (1 - B/T) 1.678 h + B/T r_e (arcsec).

Needs numpy, scipy and astropy; not run by CI.
"""
import random
import sys

import numpy as np

from selection_slopes import galaxy_matches, read_catalogue

STEP_PX = 64
N_STARS = 800


def cells_of(turned):
    """The cells' centres: the 64 px grid, or that grid turned by
    atan(1/2) about the image's centre, its cells at least 32 px from the
    edges."""
    n = 4096 // STEP_PX
    if not turned:
        return [(STEP_PX / 2 + STEP_PX * i, STEP_PX / 2 + STEP_PX * j)
                for i in range(n) for j in range(n)]
    c, s = 2.0 / np.sqrt(5.0), 1.0 / np.sqrt(5.0)
    out = []
    for i in range(-n, n + 1):
        for j in range(-n, n + 1):
            x = 2048 + STEP_PX * (i * c - j * s)
            y = 2048 + STEP_PX * (i * s + j * c)
            if STEP_PX / 2 <= x <= 4096 - STEP_PX / 2 and STEP_PX / 2 <= y <= 4096 - STEP_PX / 2:
                out.append((x, y))
    return out


def lists(catalog_dir, out_dir, n_fields, turned=False):
    for k in range(n_fields):
        rng = random.Random(1000 + k)
        galaxies, stars = [], []
        for line in open(f"{catalog_dir}/field_{k:03d}.list"):
            w = line.split()
            if not w or line.startswith("#"):
                continue
            if w[0] == "200" and float(w[3]) < 24:
                galaxies.append(w)
            elif w[0] == "100" and 18.5 < float(w[3]) < 21:
                stars.append(w)
        rng.shuffle(galaxies)
        cells = cells_of(turned)
        rng.shuffle(cells)
        with open(f"{out_dir}/f{k}.list", "w") as f:
            for c, (x, y) in enumerate(cells):
                x += rng.uniform(-0.5, 0.5)
                y += rng.uniform(-0.5, 0.5)
                if c < N_STARS:
                    w = rng.choice(stars)
                elif c - N_STARS < len(galaxies):
                    w = galaxies[c - N_STARS]
                else:
                    break
                f.write(" ".join([w[0], f"{x:.4f}", f"{y:.4f}"] + w[3:]) + "\n")


def matched(run, catalogue):
    """(field, g1, e1_int, e1, weight, hlr, mag) of each matched galaxy."""
    rows = read_catalogue(catalogue)
    out = []
    for key, t, c, g, _ in galaxy_matches(run, rows):
        bt = t["bt"][g]
        hlr = (1 - bt) * 1.678 * t["disk_h_arcsec"][g] + bt * t["bulge_re_arcsec"][g]
        out.append(np.column_stack([
            np.full(len(g), int(key("FIELD"))), np.full(len(g), key("G1")),
            t["e1_int"][g], c[:, 2], c[:, 4], hlr, t["mag"][g]]))
    return np.vstack(out).T


def field_slopes(field, g1, keep, value, w, coefficient=0):
    """Per base field (ascending), the slope (coefficient 0) or the
    intercept (1) against g1 of the weighted mean of `value` over the `keep`
    rows of each shear; NaN for a field with fewer than three shears."""
    out = []
    for f in np.unique(field):
        xs, ys = [], []
        for g in np.unique(g1):
            m = keep & (field == f) & (g1 == g)
            if w[m].sum() > 0:
                xs.append(g)
                ys.append(np.sum(w[m] * value[m]) / np.sum(w[m]))
        out.append(np.polyfit(xs, ys, 1)[coefficient] if len(xs) >= 3 else np.nan)
    return np.array(out)


def table(run, catalogue, coefficient):
    field, g1, e1_int, e1, weight, hlr, mag = matched(run, catalogue)
    kept = weight > 0
    # A slope's "m" is the slope minus 1; an intercept is itself.
    unit = 1.0 if coefficient == 0 else 0.0

    def fit(keep, value, w, minus=0.0):
        s = field_slopes(field, g1, keep, value, w, coefficient)
        s = s[np.isfinite(s)]
        if len(s) < 2:
            return "—"
        return f"{s.mean() - minus:+.4f} ± {s.std(ddof=1) / np.sqrt(len(s)):.4f}"

    bins = [("all", np.ones(len(weight), bool))]
    bins += [(f"hlr {lo:.2f}-{hi:.2f}\"", (hlr >= lo) & (hlr < hi))
             for lo, hi in [(0, 0.3), (0.3, 0.45), (0.45, 0.7), (0.7, 99)]]
    bins += [(f"I {lo}-{hi}", (mag >= lo) & (mag < hi))
             for lo, hi in [(17, 22), (22, 23), (23, 24)]]
    what = "c1" if coefficient else "m"
    print(f"{'rows':16s} {'matched':>8s} {'kept':>7s} {what + ' (kept, weighted)':>17s} "
          f"{'selection':>15s} {'estimator':>15s}")
    for name, b in bins:
        s = b & kept
        print(f"{name:16s} {int(b.sum()):8d} {int(s.sum()):7d} "
              f"{fit(s, e1, weight, unit):>17s} {fit(s, e1_int, weight):>15s} "
              f"{fit(s, e1 - e1_int, weight, unit):>15s}")


def main():
    if len(sys.argv) in (5, 6) and sys.argv[1] == "lists" and sys.argv[5:] in ([], ["turned"]):
        lists(sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5:] == ["turned"])
    elif len(sys.argv) in (4, 5) and sys.argv[1] == "table":
        table(sys.argv[2], sys.argv[3], 1 if sys.argv[4:] == ["c"] else 0)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
