#!/usr/bin/env python3
"""Render a SkyMaker list (as `stepsim catalog` writes it) with GalSim.

The peer side of the side-by-side comparison in BENCHMARKS.md ("stepsim
against GalSim on the same objects"): the same objects, the STEP1 detector
(0.206"/px, zeropoint 26 + 2.5 log10(3600 s), sky 19.2 mag/arcsec^2,
gain 4, read noise 5 e-), a coma PSF comparable to stepsim's `coma`
(Kolmogorov atmosphere convolved with an obscured, 4-spider optical PSF
with coma), Poisson noise on sky + objects. One thread (GalSim draws
object by object). Prints the wall and CPU seconds of the drawing.

    python3 tests/galsim/render_list.py LIST WIDTH HEIGHT OUT.fits [REPEATS]

With REPEATS > 1 the same image is drawn that many times in one process
(the PSF object built once, as a run of many images would) and each
image's seconds are printed: the first includes GalSim's PSF set-up, the
later ones are the per-image cost of a long run.

Needs `pip install galsim` (tested with GalSim 2.8.5). Not run by CI.
"""

import math
import sys
import time

import galsim

PIXEL_SCALE = 0.206
ZP_EFF = 26.0 + 2.5 * math.log10(3600.0)
SKY_E = 10 ** (0.4 * (ZP_EFF - 19.2)) * PIXEL_SCALE**2
GAIN = 4.0
READ_NOISE = 5.0


def psf():
    lam_over_diam = 0.8e-6 / 3.6 * 206264.806
    optics = galsim.OpticalPSF(
        lam_over_diam=lam_over_diam,
        obscuration=1.0 / 3.6,
        nstruts=4,
        strut_thick=0.02 / 3.6,
        coma1=0.25,
    )
    return galsim.Convolve([galsim.Kolmogorov(fwhm=0.85), optics])


def component(cls, size_arcsec, q, pa_deg, flux, **kw):
    # Sizes are along the major axis: GalSim's shear keeps the area, so
    # the round profile gets size * sqrt(q).
    q = max(min(q, 1.0), 0.05)
    g = cls(flux=flux, **{kw["size"]: size_arcsec * math.sqrt(q)})
    return g.shear(q=q, beta=pa_deg * galsim.degrees)


def objects(path):
    with open(path) as f:
        for line in f:
            s = line.split()
            if not s or s[0].startswith("#"):
                continue
            kind, x, y, mag = int(s[0]), float(s[1]), float(s[2]), float(s[3])
            flux = 10 ** (0.4 * (ZP_EFF - mag))
            if kind == 100:
                yield x, y, None, flux
                continue
            bt, re, bq, bpa, h, dq, dpa = map(float, s[4:11])
            parts = []
            if bt > 0 and re > 0:
                parts.append(
                    component(galsim.DeVaucouleurs, re, bq, bpa, bt * flux,
                              size="half_light_radius"))
            if bt < 1 and h > 0:
                parts.append(
                    component(galsim.Exponential, h, dq, dpa, (1 - bt) * flux,
                              size="scale_radius"))
            if parts:
                yield x, y, galsim.Add(parts), flux


def draw(path, width, height, out, p, seed):
    image = galsim.ImageF(width, height, scale=PIXEL_SCALE)
    star = p.withFlux(1.0)
    n = 0
    for x, y, gal, flux in objects(path):
        obj = star.withFlux(flux) if gal is None else galsim.Convolve([gal, p])
        stamp = obj.drawImage(scale=PIXEL_SCALE, center=galsim.PositionD(x, y))
        overlap = stamp.bounds & image.bounds
        if overlap.isDefined():
            image[overlap] += stamp[overlap]
        n += 1
    image += SKY_E
    rng = galsim.BaseDeviate(seed)
    image.addNoise(galsim.PoissonNoise(rng))
    image.addNoise(galsim.GaussianNoise(rng, sigma=READ_NOISE))
    image /= GAIN
    image.write(out)
    return n


def main():
    path, width, height, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    repeats = int(sys.argv[5]) if len(sys.argv) > 5 else 1
    p = psf()
    for r in range(repeats):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        n = draw(path, width, height, out, p, 20060101 + r)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        print(f"galsim {galsim.__version__}: image {r + 1} of {repeats}: {n} objects, "
              f"{width} x {height}, wall {wall:.2f} s, cpu {cpu:.2f} s")


if __name__ == "__main__":
    main()
