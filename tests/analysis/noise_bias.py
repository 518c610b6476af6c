#!/usr/bin/env python3
"""Where KSB+'s noise bias sits: the same galaxies at two noise levels.

    python3 tests/analysis/noise_bias.py LOW_RUN LOW_DETAILS RUN DETAILS

RUN and LOW_RUN are two runs of the same galaxies (the same SkyMaker lists,
shears and seed; docs/baseline.md, "Isolated galaxies on a grid") at the
noise under study and at much less noise; DETAILS and LOW_DETAILS the
tables `stepsim measure --details` wrote for their public halves (`image x
y e1 e2 weight flags r_g_px nu mag pgamma k e_cor1 e_cor2 sigma_gamma`). Each
row is matched to the nearest truth galaxy within 1 arcsec, and the two
runs' rows are paired by galaxy (base field, twin, shear, truth row). On
RUN's kept rows (weight > 0) whose galaxy LOW_RUN measured with a P^gamma
(kept or not), with RUN's weights, it prints per magnitude bin:

- the estimator's m as measured (slope against g1 of the weighted mean of
  gamma1 - e1_int, fitted per base field with its twin pooled, mean +-
  standard error over fields, minus 1; gamma1 = e_cor1 / P^gamma), and
  how it shifts, paired by field, when e_cor, P^gamma or both are taken
  from LOW_RUN (RUN's weights kept), and without the rows LOW_RUN cuts
  (those RUN's noise let through): which part's noise moves m;
- the numerator's shrinkage (the slope of RUN's e_cor on LOW_RUN's, both
  components), the calibration's k and P^gamma's shift (mean of
  P/P_low - 1 where LOW_RUN's passes the P^gamma cut), on the kept rows and on
  all rows, with a and b of a quadratic fit of P/P_low - 1 against
  r_g/r_g,low - 1 (a: the shift at equal r_g; b: how P^gamma follows r_g),
  and r_g's shift;
- for each cut, the rows LOW_RUN keeps that RUN flags with that cut alone
  (how many, and their shifts of P^gamma and r_g), and the rows RUN keeps
  that LOW_RUN flags with that cut alone (the same, and their m).

Measured numbers: docs/baseline.md, "Where the noise bias sits".
Needs numpy, scipy and astropy; not run by CI.
"""
import sys

import numpy as np
from scipy.spatial import cKDTree

from isolated_grid import field_slopes
from selection_slopes import FLAGS, truth_tables

PIXEL_SCALE = 0.206
MIN_PGAMMA = 0.1  # KSB+'s P^gamma cut (docs/ksb.md)
COLUMNS = "x y e1 e2 weight flags r_g_px nu mag pgamma k e_cor1 e_cor2 sigma_gamma".split()


def read_details(path):
    """{image: array of the numeric columns}, rows in file order."""
    rows = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        w = line.split()
        rows.setdefault(w[0], []).append([float(v) for v in w[1:]])
    return {k: np.array(v) for k, v in rows.items()}


def by_galaxy(run, details):
    """{(field, twin, g1, truth row): (details row, truth e1_int, truth mag)}."""
    rows = read_details(details)
    out = {}
    for image, key, t in truth_tables(run, rows):
        c = rows[image]
        gal = np.nonzero(t["kind"] == 1)[0]
        tree = cKDTree(np.column_stack([t["x"][gal], t["y"][gal]]))
        d, k = tree.query(c[:, :2], distance_upper_bound=1.0 / PIXEL_SCALE)
        head = (int(key("FIELD")), int(key("ROTATED")), round(float(key("G1")), 6))
        # One row per galaxy, the nearest.
        for r in np.argsort(d):
            if not np.isfinite(d[r]):
                break
            g = int(gal[k[r]])
            out.setdefault(head + (g,), (c[r], t["e1_int"][g], t["mag"][g]))
    return out


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    low = by_galaxy(sys.argv[1], sys.argv[2])
    high = by_galaxy(sys.argv[3], sys.argv[4])
    col = {c: i for i, c in enumerate(COLUMNS)}
    # Every galaxy LOW_RUN measured (kept or not), so that RUN's rows its
    # noise let through are counted too.
    keys = [k for k in high if k in low and np.isfinite(low[k][0][col["pgamma"]])
            and low[k][0][col["pgamma"]] > 0]
    if not keys:
        sys.exit("no galaxy is in both runs: are they the same lists and shears?")
    h = np.array([high[k][0] for k in keys])
    lo = np.array([low[k][0] for k in keys])
    e1_int = np.array([high[k][1] for k in keys])
    mag = np.array([high[k][2] for k in keys])
    field = np.array([k[0] for k in keys])
    g1 = np.array([k[2] for k in keys])
    w = h[:, col["weight"]]
    kept = w > 0
    flags = h[:, col["flags"]].astype(int)
    low_kept = lo[:, col["flags"]] == 0
    p, p_low = h[:, col["pgamma"]], lo[:, col["pgamma"]]
    e, e_low = h[:, col["e_cor1"]], lo[:, col["e_cor1"]]
    e2, e2_low = h[:, col["e_cor2"]], lo[:, col["e_cor2"]]
    rg, rg_low = h[:, col["r_g_px"]], lo[:, col["r_g_px"]]
    k, k_low = h[:, col["k"]], lo[:, col["k"]]
    # P^gamma's shifts only where LOW_RUN's passes the P^gamma cut, so that
    # a few near-zero P^gamma_low do not dominate a mean of ratios (RUN's
    # is not cut: that would select on its noise).
    both_p = np.isfinite(p) & (p_low >= MIN_PGAMMA)

    def per_field(sel, value):
        return field_slopes(field, g1, sel, value, w) - 1.0

    def fmt(v):
        v = v[np.isfinite(v)]
        if len(v) < 2:
            return "—"
        return f"{v.mean():+.4f} ± {v.std(ddof=1) / np.sqrt(len(v)):.4f}"

    def m(sel, value):
        return fmt(per_field(sel, value))

    bins = [("all", np.ones(len(keys), bool))]
    bins += [(f"I {a}-{b}", (mag >= a) & (mag < b)) for a, b in [(17, 22), (22, 23), (23, 24)]]
    print(f"{len(keys)} galaxies in both runs, {int(kept.sum())} kept in RUN, "
          f"{int((kept & ~low_kept).sum())} of them cut in LOW_RUN, "
          f"{int((kept & (p_low < MIN_PGAMMA)).sum())} with P^gamma_low < {MIN_PGAMMA}")
    print("estimator m as measured, and its shifts (paired by field) when e_cor, "
          "P^gamma or both are taken from LOW_RUN, and without the rows LOW_RUN cuts:")
    print(f"{'rows':10s} {'kept':>6s} {'m':>16s} {'e_cor low':>16s} "
          f"{'P^gamma low':>16s} {'both low':>16s} {'kept in both':>16s}")
    for name, b in bins:
        s = b & kept
        if s.sum() == 0:
            continue
        base = per_field(s, e / p - e1_int)
        print(f"{name:10s} {int(s.sum()):6d} {fmt(base):>16s} "
              f"{fmt(per_field(s, e_low / p - e1_int) - base):>16s} "
              f"{fmt(per_field(s, e / p_low - e1_int) - base):>16s} "
              f"{fmt(per_field(s, e_low / p_low - e1_int) - base):>16s} "
              f"{fmt(per_field(s & low_kept, e / p - e1_int) - base):>16s}")

    print("numerator and P^gamma, RUN against LOW_RUN (P^gamma/P^gamma_low - 1 "
          "= a + b (r_g/r_g,low - 1) + c (...)^2 fitted: a is the shift at equal r_g):")
    print(f"{'rows':10s} {'e_cor slope':>11s} {'k/k_low-1':>9s} {'P shift kept':>12s} "
          f"{'a':>7s} {'b':>5s} {'P shift all':>11s} {'a':>7s} {'b':>5s} {'r_g shift all':>13s}")

    def at_equal_rg(s):
        dr = rg[s] / rg_low[s] - 1.0
        a = np.column_stack([np.ones(s.sum()), dr, dr * dr])
        return np.linalg.lstsq(a, p[s] / p_low[s] - 1.0, rcond=None)[0][:2]

    for name, b in bins:
        s, a = b & kept & both_p, b & both_p
        if s.sum() < 10:
            continue
        slope = np.polyfit(np.r_[e_low[s], e2_low[s]], np.r_[e[s], e2[s]], 1)[0]
        (a_s, b_s), (a_a, b_a) = at_equal_rg(s), at_equal_rg(a)
        print(f"{name:10s} {slope:11.4f} {np.mean(k[s] / k_low[s] - 1):+9.4f} "
              f"{np.mean(p[s] / p_low[s] - 1):+12.4f} {a_s:+7.4f} {b_s:5.2f} "
              f"{np.mean(p[a] / p_low[a] - 1):+11.4f} {a_a:+7.4f} {b_a:5.2f} "
              f"{np.mean(rg[a] / rg_low[a] - 1):+13.4f}")

    low_flags = lo[:, col["flags"]].astype(int)
    for title, rows, alone, with_m in [
            ("rows LOW_RUN keeps that one cut alone removes in RUN:", low_kept, flags, False),
            ("rows RUN keeps that one cut alone removes in LOW_RUN:", kept, low_flags, True)]:
        print(title)
        for name, b in bins:
            for flag, bit in FLAGS.items():
                s = b & both_p & rows & (alone == bit)
                if s.sum() < 10:
                    continue
                print(f"{name:10s} {flag:10s} {int(s.sum()):6d} rows, P/P_low - 1 "
                      f"{np.mean(p[s] / p_low[s] - 1):+.4f}, r_g/r_g,low - 1 "
                      f"{np.mean(rg[s] / rg_low[s] - 1):+.4f}"
                      + (f", m {m(s, e / p - e1_int)}" if with_m else ""))


if __name__ == "__main__":
    main()
