#!/usr/bin/env python3
"""m and c of a metadetection run from its version sums, with errors that
contain the response's.

    python3 tests/analysis/metadetect_response.py RUN SUMS [RUN SUMS ...]
    python3 tests/analysis/metadetect_response.py --difference RUN_A SUMS_A RUN_B SUMS_B

SUMS is what `stepsim measure --method metadetect --version-sums SUMS`
wrote for RUN/public: per image, for each of the five versions (0, 1p, 1m,
2p, 2m), the number of objects it selects and the sums of their e1 and e2.
The unsheared version's sums are those of the submission's weighted rows
before R is applied, so the submission itself is not needed. The truth
comes from RUN/private/datasets.json (each dataset's PSF and shear, each
image's base field). Several runs are taken together, their datasets
grouped by PSF name and their fields by number: runs that differ only in
their shears and share `run.seed` (the same galaxies, paired shears). A
dataset that lacks some of the group's fields is left out, with a line
saying so; runs of other galaxies and other numbers of fields are
better measured one by one and their m's averaged.

For each PSF, over its datasets d (shear g_d) and base fields f (an
image and its rotated twin):

    e_d = <e>_d / R_d  (R's diagonal, as the rows use it),
    m_i = slope of e_d,i against g_d,i over the datasets - 1 (i = 1, 2),
    c_i = the intercept; m = (m1 + m2) / 2,

with <e>_d the mean over all of d's images' selected objects and R_d the
response of the images pooled in one of three ways: per dataset (what
`measure` applies), per field and dataset (each field's own), or over
all the PSF's datasets (one R for every shear; valid where R does not
depend on the shear, which the per-dataset R's printed here test). The
errors are the delete-one jackknife over base fields of the whole
estimator, numerator and R recomputed without the field: the same
galaxies make both, so their fluctuations are not independent, and adding
R's own error to the fields' scatter counts it twice where they move
together. Printed for comparison: the mean and standard error over fields
of the per-field m with the per-dataset R (the scatter a field-by-field
score sees, which leaves R's noise out).

With --difference, two runs of the same galaxies and shears that differ
in one setting (e.g. `population.lens_positions`): for each PSF, m and c
of each run and of A minus B, with the jackknife over the base fields
they share, both runs' numerators and R's recomputed without the field,
so what the two runs have in common (the galaxies, their shape noise)
cancels in the difference's error.

Measured numbers: docs/metacal.md, "Metadetection". Needs numpy; not run
by CI.
"""
import json
import sys

import numpy as np

STEP = 0.01

# {dataset: the shear of `--unshear`'s version (-ĝ0)}, from the sums.
ORIGIN = {}


def read_sums(path):
    """({image: (dataset, 6 x 3 array of [sum e1, sum e2, n])}, {dataset:
    the shear it was sheared back by}): the five versions' rows, then
    `--unshear`'s version's (zeros, and no entry in the second dict,
    without it)."""
    out = {}
    back = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        w = line.split()
        v = np.array([float(x) for x in w[2:]])
        if len(v) == 20:
            back[w[1]] = (v[15], v[16])
            v = np.append(v[:15], v[17:])
        else:
            # No second measurement: its row is empty, so that runs with
            # and without one can be pooled.
            v = np.append(v, np.zeros(3))
        out[w[0]] = (w[1], v.reshape(6, 3)[:, [1, 2, 0]])
    return out, back


def response(s):
    """R's diagonal from summed version sums (the five versions' rows of
    s), or None."""
    s = s[:5]
    if np.any(s[1:, 2] <= 0):
        return None
    mean = s[:, :2] / s[:, 2:3]
    r = np.array([(mean[1, 0] - mean[2, 0]) / (2 * STEP), (mean[3, 1] - mean[4, 1]) / (2 * STEP)])
    return r if np.all(r > 0) else None


def estimate(cells, datasets, shears, fields, mode):
    """(m1, m2, c1, c2) from cells[(dataset, field)] = summed version sums
    over the given fields; mode is "dataset", "field" or "pooled"."""
    pooled = sum(cells[(d, f)] for d in datasets for f in fields)
    rp = response(pooled)
    est = []
    for d in datasets:
        tot = sum(cells[(d, f)] for f in fields)
        if mode == "field":
            num = np.zeros(2)
            for f in fields:
                s = cells[(d, f)]
                r = response(s)
                if r is None:
                    return None
                num += s[0, :2] / r
            e = num / tot[0, 2]
        elif mode == "unshear":
            # ĝ0 + R^-1 <e> of the version sheared back by ĝ0 (origin = -ĝ0).
            r = response(tot)
            if r is None or tot[5, 2] <= 0:
                return None
            e = -np.array(ORIGIN[d]) + tot[5, :2] / tot[5, 2] / r
        else:
            r = response(tot) if mode == "dataset" else rp
            if r is None:
                return None
            e = tot[0, :2] / tot[0, 2] / r
        est.append(e)
    est = np.array(est)
    g = np.array([shears[d] for d in datasets])
    out = []
    for i in range(2):
        if np.ptp(g[:, i]) == 0:
            out.append((np.nan, est[:, i].mean()))
        else:
            slope, icept = np.polyfit(g[:, i], est[:, i], 1)
            out.append((slope - 1, icept))
    return np.array([out[0][0], out[1][0], out[0][1], out[1][1]])


def jackknife(cells, datasets, shears, fields, mode):
    full = estimate(cells, datasets, shears, fields, mode)
    parts = [estimate(cells, datasets, shears, [g for g in fields if g != f], mode) for f in fields]
    if full is None or any(p is None for p in parts):
        return None, None
    parts = np.array(parts)
    n = len(fields)
    # m is the mean of the components a design tests (m2 is nan when
    # every dataset has the same g2).
    both = lambda v: np.nanmean(v[..., :2], axis=-1)
    with np.errstate(invalid="ignore"):
        m = np.column_stack([parts, both(parts)])
        err = np.sqrt((n - 1) / n * ((m - m.mean(0)) ** 2).sum(0))
    return np.append(full, both(full)), err


def load(args):
    """(datasets by PSF, shears, cells by PSF) of the runs in args (RUN
    SUMS pairs), dataset ids prefixed with the run's place."""
    by_psf = {}
    field_of = {}
    shears = {}
    sums = {}
    for k in range(0, len(args), 2):
        # Ids are prefixed with the run's place: two runs may share them.
        run = f"{k // 2}:"
        truth = json.load(open(f"{args[k]}/private/datasets.json"))
        for d in truth["datasets"]:
            by_psf.setdefault(d["psf"], []).append(run + d["dataset"])
            shears[run + d["dataset"]] = (d["g1"], d["g2"])
            for im in d["images"]:
                field_of[run + im["image"]] = im["field"]
        read, back = read_sums(args[k + 1])
        for image, (dataset, s) in read.items():
            sums[run + image] = (run + dataset, s)
        for dataset, origin in back.items():
            ORIGIN[run + dataset] = origin
    cells_by_psf = {}
    for psf, datasets in by_psf.items():
        cells = {}
        for image, (dataset, s) in sums.items():
            if dataset in datasets:
                k = (dataset, field_of[image])
                cells[k] = cells.get(k, 0) + s
        cells_by_psf[psf] = cells
    return by_psf, shears, cells_by_psf


def complete(datasets, cells, fields):
    """(the datasets that have every one of `fields`, a line for each left
    out): the estimators pair datasets field by field."""
    kept, left = [], []
    for d in datasets:
        have = sum((d, f) in cells for f in fields)
        if have == len(fields):
            kept.append(d)
        else:
            left.append(f"  dataset {d} left out: it has {have} of the {len(fields)} fields"
                        " (runs given together must have the same base fields)")
    return kept, left


def difference(args):
    """m and c of run A, of run B and of A - B per PSF, jackknifed over the
    shared base fields."""
    runs = [load(args[0:2]), load(args[2:4])]
    for psf in sorted(set(runs[0][0]) & set(runs[1][0])):
        parts = []
        for by_psf, shears, cells_by_psf in runs:
            cells = cells_by_psf[psf]
            parts.append((cells, by_psf[psf], shears, {f for (_, f) in cells}))
        fields = sorted(parts[0][3] & parts[1][3])
        print(f"PSF {psf}: {len(fields)} shared fields")
        kept = [complete(ds, c, fields) for c, ds, _, _ in parts]
        for _, left in kept:
            for line in left:
                print(line)
        parts = [(c, ds, sh) for (c, _, sh, _), (ds, _) in zip(parts, kept)]
        for mode, name in [("dataset", "R per dataset"),
                           ("pooled", "R pooled over the PSF's datasets")]:
            def est(fs):
                e = [estimate(c, ds, sh, fs, mode) for c, ds, sh in parts]
                if any(v is None for v in e):
                    return None
                e = [np.append(v, np.nanmean(v[:2])) for v in e]
                return np.array([e[0], e[1], e[0] - e[1]])
            full = est(fields)
            jk = [est([g for g in fields if g != f]) for f in fields]
            if full is None or any(v is None for v in jk):
                print(f"  {name}: undefined (a response without a field)")
                continue
            jk = np.array(jk)
            n = len(fields)
            with np.errstate(invalid="ignore"):
                err = np.sqrt((n - 1) / n * ((jk - jk.mean(0)) ** 2).sum(0))
            for row, label in enumerate(["A", "B", "A - B"]):
                v, e = full[row], err[row]
                print(f"  {name}, {label}: m {v[4]:+.4f} ± {e[4]:.4f}"
                      f"  (m1 {v[0]:+.4f} ± {e[0]:.4f}), c1 {v[2]:+.5f} ± {e[2]:.5f},"
                      f" c2 {v[3]:+.5f} ± {e[3]:.5f}")


def main():
    args = sys.argv[1:]
    if args[:1] == ["--difference"]:
        if len(args) != 5:
            sys.exit(__doc__)
        difference(args[1:])
        return
    if len(args) < 2 or len(args) % 2:
        sys.exit(__doc__)
    by_psf, shears, cells_by_psf = load(args)
    for psf, datasets in by_psf.items():
        cells = cells_by_psf[psf]
        fields = sorted({f for (_, f) in cells})
        datasets, left = complete(datasets, cells, fields)
        n_rows = sum(cells[(d, f)][0, 2] for d in datasets for f in fields)
        print(f"PSF {psf}: {len(datasets)} datasets, {len(fields)} fields, "
              f"{n_rows:.0f} selected objects (unsheared version)")
        for line in left:
            print(line)
        for d in datasets:
            tot = sum(cells[(d, f)] for f in fields)
            r = response(tot)
            print(f"  dataset {d} g = ({shears[d][0]:+.4f}, {shears[d][1]:+.4f}): "
                  f"R11 {r[0]:.4f}  R22 {r[1]:.4f}")
        # The per-field scatter with the per-dataset R, as a score by field sees it.
        rs = {d: response(sum(cells[(d, f)] for f in fields)) for d in datasets}
        per_field = []
        for f in fields:
            cf = {(d, f): cells[(d, f)] for d in datasets}
            est = np.array([cf[(d, f)][0, :2] / cf[(d, f)][0, 2] / rs[d] for d in datasets])
            g = np.array([shears[d] for d in datasets])
            ms = [np.polyfit(g[:, i], est[:, i], 1)[0] - 1 if np.ptp(g[:, i]) else np.nan
                  for i in range(2)]
            per_field.append(ms + [np.nanmean(ms)])
        per_field = np.array(per_field)
        se = per_field.std(0, ddof=1) / np.sqrt(len(fields))
        mean = per_field.mean(0)
        comps = ", ".join(f"m{i + 1} {mean[i]:+.4f} ± {se[i]:.4f}" if np.isfinite(mean[i])
                          else f"m{i + 1} untested (one g{i + 1})" for i in range(2))
        print(f"  per field, R per dataset (fields' scatter only): m {mean[2]:+.4f} ± {se[2]:.4f}"
              f"  ({comps})")
        modes = [("dataset", "R per dataset"), ("field", "R per field and dataset"),
                 ("pooled", "R pooled over the PSF's datasets")]
        if all(d in ORIGIN for d in datasets):
            modes.append(("unshear", "sheared back by ĝ0 (--unshear's rows)"))
        for mode, name in modes:
            v, e = jackknife(cells, datasets, shears, fields, mode)
            if v is None:
                print(f"  {name}: undefined (a response without a field)")
                continue
            comps = ", ".join(f"m{i + 1} {v[i]:+.4f} ± {e[i]:.4f}" if np.isfinite(v[i])
                              else f"m{i + 1} untested (one g{i + 1})" for i in range(2))
            print(f"  {name}, jackknife over fields: m {v[4]:+.4f} ± {e[4]:.4f}  ({comps}),"
                  f"  c1 {v[2]:+.5f} ± {e[2]:.5f}, c2 {v[3]:+.5f} ± {e[3]:.5f}")


if __name__ == "__main__":
    main()
