#!/usr/bin/env python3
"""How far a run's rotated twins cancel, from metadetection's version sums.

    python3 tests/analysis/twin_stats.py RUN SUMS

SUMS is what `stepsim measure --method metadetect --version-sums SUMS`
wrote for RUN/public (docs/metacal.md, "Metadetection"); RUN/private/
datasets.json says which image is which base field and which is the
rotated twin. For each dataset (a shear) and each component i, over the
base fields f:

    <e_i>  the mean e_i of the objects the unsheared version selects,
           per image (the field's image and its twin apart);
    R_ii   (<e_i>_ip - <e_i>_im) / 0.02 of the same image.

Printed: the standard deviation over fields of <e_i> in the field's
image and in its twin, their correlation, and the standard deviation of
the pair's mean (what a score of the two together sees); the same for
R_ii. A twin cancels the field's shapes when the correlation of <e_i>
is -1 and the pair's mean stays put from field to field.
"""

import json
import sys

import numpy as np


def read(run, sums):
    datasets = json.load(open(f"{run}/private/datasets.json"))["datasets"]
    where = {}
    for d in datasets:
        for im in d["images"]:
            where[im["image"]] = ((d["psf"], d["g1"], d["g2"]), im["field"], im["rotated"])
    table = {}
    for line in open(sums):
        if line.startswith("#"):
            continue
        words = line.split()
        table[where[words[0]]] = np.array([float(w) for w in words[2:]])
    return table


def mean_e(s, i):
    """<e_i> of the unsheared version (columns n, Σe1, Σe2 first)."""
    return s[1 + i] / s[0]


def response(s, i):
    """R_ii from versions ip and im (columns 3–5, 6–8 for 1p, 1m; 9–14 for 2)."""
    p, m = 3 + 6 * i, 6 + 6 * i
    return (s[p + 1 + i] / s[p] - s[m + 1 + i] / s[m]) / 0.02


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    table = read(sys.argv[1], sys.argv[2])
    datasets = sorted({k[0] for k in table})
    fields = sorted({k[1] for k in table})
    if len(fields) < 3:
        sys.exit("need at least three base fields")
    print(f"{len(fields)} base fields")
    print("dataset (psf, g1, g2)  e_i | sd field, twin | corr | sd pair mean || R_ii sd field, twin | corr | sd pair mean")
    for d in datasets:
        for i in (0, 1):
            cols = []
            for f in (mean_e, response):
                a = np.array([f(table[(d, k, False)], i) for k in fields])
                b = np.array([f(table[(d, k, True)], i) for k in fields])
                cols.append(
                    f"{a.std(ddof=1):.5f} {b.std(ddof=1):.5f} | "
                    f"{np.corrcoef(a, b)[0, 1]:+.2f} | {((a + b) / 2).std(ddof=1):.5f}"
                )
            print(f"{d}  e{i + 1} | {cols[0]} || {cols[1]}")


if __name__ == "__main__":
    main()
