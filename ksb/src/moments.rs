//! Gaussian-weighted moments and the KSB polarisabilities.
//!
//! ## The quantities (KSB 1995 appendix; Hoekstra et al. 1998; written out here)
//!
//! About the object centre θ = 0, with the round Gaussian weight
//! W(θ) = w(|θ|²) = exp(−|θ|² / 2 r_g²), so that w′ = dw/d|θ|² = −W / 2r_g²
//! and w″ = W / 4r_g⁴, and with the spin-2 combinations
//! η = (θ₁² − θ₂², 2 θ₁θ₂):
//!
//! * trace T = ∫ W I |θ|², polarisation q_α = ∫ W I η_α, ellipticity
//!   e_α = q_α / T (paper eq. 11; the distortion type, |e| = (1−β²)/(1+β²)
//!   for W = 1).
//! * **Shear.** Shearing the object, I → I(θ − Γθ) with
//!   Γ = [[γ₁, γ₂], [γ₂, −γ₁]], changes |θ|² by 2 γ_β η_β and η_α by
//!   2 γ_α |θ|² under the change of variables, so to first order
//!   δq_α = X^sh_αβ γ_β and δT = E^sh_β γ_β with
//!   X^sh_αβ = ∫ I (2 W |θ|² δ_αβ + 2 w′ η_α η_β),
//!   E^sh_β  = ∫ I (2 W + 2 w′ |θ|²) η_β,
//!   hence δe_α = P^sh_αβ γ_β, **P^sh_αβ = (X^sh_αβ − e_α E^sh_β) / T**.
//! * **Smear.** Convolving with a small kernel of unit flux whose second
//!   moments have the traceless part ½[[p₁, p₂], [p₂, −p₁]] (that is,
//!   p_α = ∫ kernel · η_α) changes I by ½ D_ij ∂_i∂_j I. Integrating by parts
//!   twice, δq_α = X^sm_αβ p_β and δT = E^sm_β p_β with
//!   X^sm_αβ = ∫ I ((W + 2 w′ |θ|²) δ_αβ + w″ η_α η_β),
//!   E^sm_β  = ∫ I (2 w′ + w″ |θ|²) η_β,
//!   hence δe_α = P^sm_αβ p_β, **P^sm_αβ = (X^sm_αβ − e_α E^sm_β) / T**.
//!
//! Both formulae are checked in the tests by finite differences: shearing
//! and smearing an analytic Gaussian changes e by P^sh γ and P^sm p.
//!
//! ## Discretisation (KSB table row "Quadrupole estimate", "Approx")
//! Integrals are sums over pixel centres (Δθ = 1 pixel) at their exact
//! offsets from the (sub-pixel) centre, over the disc |θ| ≤ θ_max =
//! `window_radius_rg` × r_g; no interpolation. Pixel values are electrons.
//!
//! ## Noise
//! With independent pixel noise of variance v, δe_α = Σ W (η_α − e_α |θ|²) n / T,
//! so Var e_α = Σ v W² (η_α − e_α |θ|²)² / T². The Gaussian-weighted S/N is
//! ν = Σ W I / sqrt(Σ v W²).

use crate::image::Image;
use crate::linalg::Mat2;

/// How the variance of each pixel is obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelNoise {
    /// Variance of the background (sky + read noise), electrons².
    pub background_var: f64,
    /// Add the pixel's own (positive) value as Poisson variance.
    pub poisson: bool,
}

impl PixelNoise {
    /// The variance of a pixel of (background-subtracted) value `v` electrons.
    #[inline]
    pub fn var(&self, v: f64) -> f64 {
        if self.poisson {
            self.background_var + v.max(0.0)
        } else {
            self.background_var
        }
    }
}

/// The weighted integrals of one object: everything the KSB formulae need.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct KsbIntegrals {
    /// Weight scale r_g in pixels.
    pub sigma_w: f64,
    /// Σ W I (electrons).
    pub s0: f64,
    /// Σ W I (x, y) about the centre: zero at a windowed centroid.
    pub first: [f64; 2],
    /// T = Σ W I |θ|².
    pub trace: f64,
    /// q_α = Σ W I η_α.
    pub q: [f64; 2],
    /// X^sh.
    pub xsh: Mat2,
    /// E^sh.
    pub esh: [f64; 2],
    /// X^sm.
    pub xsm: Mat2,
    /// E^sm.
    pub esm: [f64; 2],
    /// Variance of e (per component) from pixel noise; 0 without a noise model.
    pub var_e: [f64; 2],
    /// Σ v W² (for the S/N); 0 without a noise model.
    pub var_s0: f64,
    /// True when the window reaches beyond the image.
    pub clipped: bool,
}

/// The KSB shape of one object at one weight scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KsbShape {
    /// Weight scale r_g in pixels.
    pub sigma_w: f64,
    /// Weighted ellipticity e_α = q_α / T (distortion type).
    pub e: [f64; 2],
    /// Smear polarisability P^sm.
    pub psm: Mat2,
    /// Shear polarisability P^sh.
    pub psh: Mat2,
    /// Noise σ of e per component (0 without a noise model).
    pub sigma_e: [f64; 2],
    /// Gaussian-weighted S/N ν (infinite without a noise model).
    pub sn: f64,
    /// Gaussian-matched flux 2 Σ W I: the flux of a Gaussian of σ = r_g.
    pub flux_e: f64,
}

impl KsbIntegrals {
    /// The Gaussian-weighted S/N ν = S0 / √(Σ v W²) (infinite without a
    /// noise model).
    pub fn sn(&self) -> f64 {
        if self.var_s0 > 0.0 {
            self.s0 / self.var_s0.sqrt()
        } else {
            f64::INFINITY
        }
    }

    /// The shape, or `None` if the weighted flux or trace is not positive.
    pub fn shape(&self) -> Option<KsbShape> {
        let t = self.trace;
        if !(self.s0 > 0.0 && t > 0.0 && t.is_finite()) {
            return None;
        }
        let e = [self.q[0] / t, self.q[1] / t];
        let mut psm = [[0.0; 2]; 2];
        let mut psh = [[0.0; 2]; 2];
        for a in 0..2 {
            for b in 0..2 {
                psh[a][b] = (self.xsh[a][b] - e[a] * self.esh[b]) / t;
                psm[a][b] = (self.xsm[a][b] - e[a] * self.esm[b]) / t;
            }
        }
        let sn = self.sn();
        Some(KsbShape {
            sigma_w: self.sigma_w,
            e,
            psm,
            psh,
            sigma_e: [self.var_e[0].sqrt(), self.var_e[1].sqrt()],
            sn,
            flux_e: 2.0 * self.s0,
        })
    }
}

/// Pixel range `[lo, hi]` covered by a window of `radius` about `c`, clipped
/// to `0..n`; the flag says whether it was clipped.
fn window_range(c: f64, radius: f64, n: usize) -> (usize, usize, bool) {
    let lo = (c - radius).ceil();
    let hi = (c + radius).floor();
    let clipped = lo < 0.0 || hi > n as f64 - 1.0;
    let lo = lo.max(0.0) as usize;
    let hi = (hi.min(n as f64 - 1.0)).max(-1.0);
    if hi < 0.0 || (lo as f64) > hi {
        return (1, 0, true);
    }
    (lo, hi as usize, clipped)
}

/// The weighted flux, first moments and trace of [`ksb_integrals`] (`s0`,
/// `first`, `trace`), and whether the window was clipped: what the
/// centroid iteration needs ([`crate::centroid::windowed`]), without the
/// other seven sums.
///
/// The fast routine: the weight is separable, W = wx(dx) wy(dy), so each
/// row of the disc is summed once against wx, wx dx and wx dx² (in four
/// interleaved partial sums, which the compiler turns into vector
/// instructions) and the row's three sums are weighted by wy, wy dy and
/// dy²: Σ W I = Σ_rows wy t₀, Σ W I dx = Σ wy t₁, Σ W I dy = Σ wy dy t₀,
/// Σ W I |θ|² = Σ wy (t₂ + dy² t₀). The same pixels as its twin
/// [`window_moments_slow`] (the per-pixel sums of [`ksb_integrals`]),
/// in another order: the sums agree to rounding, within 1e-13 of Σ W |I|
/// (times radius and radius² for the first moments and trace; tested), not
/// bit for bit.
pub fn window_moments(img: &Image, xc: f64, yc: f64, sigma_w: f64, radius: f64) -> WindowMoments {
    let win = Window::new(img, xc, yc, sigma_w, radius);
    // wx, wx dx, wx dx² of every column, each a run of `n`.
    let n = win.cols.len();
    let mut f = Vec::with_capacity(3 * n);
    f.extend(win.cols.iter().map(|c| c.wx));
    f.extend(win.cols.iter().map(|c| c.wx * c.dx));
    f.extend(win.cols.iter().map(|c| c.wx * c.dx2));
    let (w0, rest) = f.split_at(n);
    let (w1, w2) = rest.split_at(n);
    let (mut s0, mut sx, mut sy, mut sr2) = (0.0, 0.0, 0.0, 0.0);
    for iy in win.rows.clone() {
        let dy = iy as f64 - yc;
        let dy2 = dy * dy;
        if dy2 > win.r2max {
            continue;
        }
        let wy = (-dy2 * win.inv2s2).exp();
        let span = win.span(dy2);
        let row = &img.data[iy * img.width + win.x0..][span.clone()];
        let [t0, t1, t2] = row_sums(row, &w0[span.clone()], &w1[span.clone()], &w2[span]);
        s0 += wy * t0;
        sx += wy * t1;
        sy += wy * t0 * dy;
        sr2 += wy * (t2 + dy2 * t0);
    }
    WindowMoments {
        s0,
        first: [sx, sy],
        trace: sr2,
        clipped: win.clipped,
    }
}

/// Σ a v, Σ b v, Σ c v over one row `v`, in four interleaved partial sums.
#[inline]
fn row_sums(v: &[f32], a: &[f64], b: &[f64], c: &[f64]) -> [f64; 3] {
    const L: usize = 4;
    let (mut p0, mut p1, mut p2) = ([0.0f64; L], [0.0f64; L], [0.0f64; L]);
    let n = v.len() / L * L;
    for (((v, a), b), c) in v[..n]
        .chunks_exact(L)
        .zip(a[..n].chunks_exact(L))
        .zip(b[..n].chunks_exact(L))
        .zip(c[..n].chunks_exact(L))
    {
        for l in 0..L {
            let x = f64::from(v[l]);
            p0[l] += a[l] * x;
            p1[l] += b[l] * x;
            p2[l] += c[l] * x;
        }
    }
    let mut t = [
        (p0[0] + p0[2]) + (p0[1] + p0[3]),
        (p1[0] + p1[2]) + (p1[1] + p1[3]),
        (p2[0] + p2[2]) + (p2[1] + p2[3]),
    ];
    for k in n..v.len() {
        let x = f64::from(v[k]);
        t[0] += a[k] * x;
        t[1] += b[k] * x;
        t[2] += c[k] * x;
    }
    t
}

/// The slow, obvious twin of [`window_moments`]: every pixel of the
/// window's bounding box tested against the disc, and its weight
/// wx(dx) wy(dy) times its value added to each of the four sums, pixel by
/// pixel: the sums of [`ksb_integrals`] bit for bit (tested). For the tests.
#[cfg_attr(
    not(test),
    expect(dead_code, reason = "a slow twin, the reference of a unit test")
)]
pub fn window_moments_slow(
    img: &Image,
    xc: f64,
    yc: f64,
    sigma_w: f64,
    radius: f64,
) -> WindowMoments {
    let win = Window::new(img, xc, yc, sigma_w, radius);
    let (mut s0, mut sx, mut sy, mut sr2) = (0.0, 0.0, 0.0, 0.0);
    for iy in win.rows.clone() {
        let dy = iy as f64 - yc;
        let dy2 = dy * dy;
        if dy2 > win.r2max {
            continue;
        }
        let wy = (-dy2 * win.inv2s2).exp();
        let row = &img.data[iy * img.width..(iy + 1) * img.width];
        for (k, ix) in (win.x0..=win.x1).enumerate() {
            let dx = ix as f64 - xc;
            let r2 = dx * dx + dy2;
            if r2 > win.r2max {
                continue;
            }
            let wi = win.cols[k].wx * wy * f64::from(row[ix]);
            s0 += wi;
            sx += wi * dx;
            sy += wi * dy;
            sr2 += wi * r2;
        }
    }
    WindowMoments {
        s0,
        first: [sx, sy],
        trace: sr2,
        clipped: win.clipped,
    }
}

/// One column of a window: its offset from the centre, the offset squared,
/// and the x factor of the Gaussian weight.
#[derive(Debug, Clone, Copy)]
struct Column {
    dx: f64,
    dx2: f64,
    wx: f64,
}

/// The pixels of a window (columns `x0..=x1`, rows `rows`), whether it
/// reaches past the image, and each column's offset and x factor of the
/// Gaussian weight: what [`window_moments`] and [`ksb_integrals`] share.
struct Window {
    x0: usize,
    x1: usize,
    rows: std::ops::Range<usize>,
    clipped: bool,
    inv2s2: f64,
    r2max: f64,
    cols: Vec<Column>,
}

impl Window {
    fn new(img: &Image, xc: f64, yc: f64, sigma_w: f64, radius: f64) -> Self {
        let (x0, x1, cx) = window_range(xc, radius, img.width);
        let (y0, y1, cy) = window_range(yc, radius, img.height);
        let inv2s2 = 1.0 / (2.0 * sigma_w * sigma_w);
        let cols: Vec<Column> = (x0..=x1)
            .map(|i| {
                let d = i as f64 - xc;
                Column {
                    dx: d,
                    dx2: d * d,
                    wx: (-d * d * inv2s2).exp(),
                }
            })
            .collect();
        // An empty window (y0 > y1) has no rows.
        let rows = if y0 > y1 {
            0..0
        } else {
            y0..y1.min(img.height.saturating_sub(1)) + 1
        };
        Self {
            x0,
            x1,
            rows,
            clipped: cx || cy,
            inv2s2,
            r2max: radius * radius,
            cols,
        }
    }

    /// The columns (indices into `cols`) of the row at `dy2` from the
    /// centre whose pixels are not outside the disc, `!(dx² + dy² >
    /// radius²)` with the very sums the per-pixel test makes (a NaN keeps
    /// the pixel, as it did). They are one run: `dx` rounds monotonically
    /// in the column, so `dx²`, and `dx² + dy²`, fall then rise along the
    /// row.
    fn span(&self, dy2: f64) -> std::ops::Range<usize> {
        let inside = |c: &Column| {
            let r2 = c.dx2 + dy2;
            r2 <= self.r2max || r2.is_nan() || self.r2max.is_nan()
        };
        let Some(a) = self.cols.iter().position(inside) else {
            return 0..0;
        };
        let b = self.cols.iter().rposition(inside).map_or(a, |b| b + 1);
        a..b
    }
}

/// What [`window_moments`] measures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowMoments {
    /// Σ W I.
    pub s0: f64,
    /// Σ W I (x, y) about the centre.
    pub first: [f64; 2],
    /// Σ W I |θ|².
    pub trace: f64,
    /// The window reached past the image's edge.
    pub clipped: bool,
}

/// The KSB integrals of `img` about `(xc, yc)` (array coordinates) with
/// weight scale `sigma_w` over the disc of radius `radius` pixels. The fast
/// routine: separable weights, one pass, raw power sums combined at the end.
pub fn ksb_integrals(
    img: &Image,
    xc: f64,
    yc: f64,
    sigma_w: f64,
    radius: f64,
    noise: Option<PixelNoise>,
) -> KsbIntegrals {
    let win = Window::new(img, xc, yc, sigma_w, radius);
    let clipped = win.clipped;
    // Raw sums: S0, Sx, Sy, Sr2, Seta[2], See[3] (11, 12, 22), Ser2[2].
    let (mut s0, mut sx, mut sy, mut sr2) = (0.0, 0.0, 0.0, 0.0);
    let (mut se1, mut se2) = (0.0, 0.0);
    let (mut see11, mut see12, mut see22) = (0.0, 0.0, 0.0);
    let (mut ser1, mut ser2) = (0.0, 0.0);
    // Noise sums: Σ v W², Σ v W² η⊗η (diagonal), Σ v W² η θ², Σ v W² θ⁴.
    let (mut nw2, mut nee1, mut nee2, mut ner1, mut ner2, mut nr4) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for iy in win.rows.clone() {
        let dy = iy as f64 - yc;
        let dy2 = dy * dy;
        if dy2 > win.r2max {
            continue;
        }
        let wy = (-dy2 * win.inv2s2).exp();
        let span = win.span(dy2);
        let row = &img.data[iy * img.width + win.x0..][span.clone()];
        for (c, &v) in win.cols[span].iter().zip(row) {
            let dx = c.dx;
            let r2 = c.dx2 + dy2;
            let v = f64::from(v);
            let w = c.wx * wy;
            let wi = w * v;
            let e1 = c.dx2 - dy2;
            let e2 = 2.0 * dx * dy;
            s0 += wi;
            sx += wi * dx;
            sy += wi * dy;
            sr2 += wi * r2;
            se1 += wi * e1;
            se2 += wi * e2;
            see11 += wi * e1 * e1;
            see12 += wi * e1 * e2;
            see22 += wi * e2 * e2;
            ser1 += wi * e1 * r2;
            ser2 += wi * e2 * r2;
            if let Some(n) = noise {
                let vw2 = n.var(v) * w * w;
                nw2 += vw2;
                nee1 += vw2 * e1 * e1;
                nee2 += vw2 * e2 * e2;
                ner1 += vw2 * e1 * r2;
                ner2 += vw2 * e2 * r2;
                nr4 += vw2 * r2 * r2;
            }
        }
    }
    let s2 = sigma_w * sigma_w;
    let s4 = s2 * s2;
    let see = [[see11, see12], [see12, see22]];
    let seta = [se1, se2];
    let ser = [ser1, ser2];
    let mut xsh = [[0.0; 2]; 2];
    let mut xsm = [[0.0; 2]; 2];
    for a in 0..2 {
        for b in 0..2 {
            let d = if a == b { 1.0 } else { 0.0 };
            // 2 W θ² δ + 2 w′ η η  with w′ = −W / 2σ².
            xsh[a][b] = 2.0 * sr2 * d - see[a][b] / s2;
            // (W + 2 w′ θ²) δ + w″ η η  with w″ = W / 4σ⁴.
            xsm[a][b] = (s0 - sr2 / s2) * d + see[a][b] / (4.0 * s4);
        }
    }
    let esh = [0, 1].map(|b| 2.0 * seta[b] - ser[b] / s2);
    let esm = [0, 1].map(|b| -seta[b] / s2 + ser[b] / (4.0 * s4));
    let var_e = if noise.is_some() && sr2 > 0.0 {
        let e = [se1 / sr2, se2 / sr2];
        let nee = [nee1, nee2];
        let ner = [ner1, ner2];
        [0, 1].map(|a| (nee[a] - 2.0 * e[a] * ner[a] + e[a] * e[a] * nr4) / (sr2 * sr2))
    } else {
        [0.0; 2]
    };
    KsbIntegrals {
        sigma_w,
        s0,
        first: [sx, sy],
        trace: sr2,
        q: seta,
        xsh,
        esh,
        xsm,
        esm,
        var_e,
        var_s0: nw2,
        clipped,
    }
}

/// Reference twin of [`ksb_integrals`]: evaluates W, w′, w″ per pixel and
/// accumulates each KSB integrand exactly as written in the module docs, and
/// the noise of e from its per-pixel derivative in a second pass. Slow and
/// obvious; used by the tests.
#[cfg_attr(
    not(test),
    expect(dead_code, reason = "a slow twin, the reference of a unit test")
)]
pub fn ksb_integrals_slow(
    img: &Image,
    xc: f64,
    yc: f64,
    sigma_w: f64,
    radius: f64,
    noise: Option<PixelNoise>,
) -> KsbIntegrals {
    let weight = |r2: f64| (-r2 / (2.0 * sigma_w * sigma_w)).exp();
    let wp = |r2: f64| -weight(r2) / (2.0 * sigma_w * sigma_w);
    let wpp = |r2: f64| weight(r2) / (4.0 * sigma_w.powi(4));
    let mut out = KsbIntegrals {
        sigma_w,
        ..KsbIntegrals::default()
    };
    let mut pixels = Vec::new();
    for iy in 0..img.height {
        for ix in 0..img.width {
            let (dx, dy) = (ix as f64 - xc, iy as f64 - yc);
            let r2 = dx * dx + dy * dy;
            if r2 <= radius * radius {
                pixels.push((dx, dy, f64::from(img.at(ix, iy))));
            }
        }
    }
    let (lo_x, hi_x) = (xc - radius, xc + radius);
    let (lo_y, hi_y) = (yc - radius, yc + radius);
    out.clipped = lo_x.ceil() < 0.0
        || hi_x.floor() > img.width as f64 - 1.0
        || lo_y.ceil() < 0.0
        || hi_y.floor() > img.height as f64 - 1.0;
    for &(dx, dy, i) in &pixels {
        let r2 = dx * dx + dy * dy;
        let eta = [dx * dx - dy * dy, 2.0 * dx * dy];
        let (w, w1, w2) = (weight(r2), wp(r2), wpp(r2));
        out.s0 += w * i;
        out.first[0] += w * i * dx;
        out.first[1] += w * i * dy;
        out.trace += w * i * r2;
        for a in 0..2 {
            out.q[a] += w * i * eta[a];
            out.esh[a] += i * (2.0 * w + 2.0 * w1 * r2) * eta[a];
            out.esm[a] += i * (2.0 * w1 + w2 * r2) * eta[a];
            for b in 0..2 {
                let d = if a == b { 1.0 } else { 0.0 };
                out.xsh[a][b] += i * (2.0 * w * r2 * d + 2.0 * w1 * eta[a] * eta[b]);
                out.xsm[a][b] += i * ((w + 2.0 * w1 * r2) * d + w2 * eta[a] * eta[b]);
            }
        }
    }
    if let Some(n) = noise {
        let e = [out.q[0] / out.trace, out.q[1] / out.trace];
        for &(dx, dy, i) in &pixels {
            let r2 = dx * dx + dy * dy;
            let eta = [dx * dx - dy * dy, 2.0 * dx * dy];
            let w = weight(r2);
            let v = n.var(i);
            out.var_s0 += v * w * w;
            for a in 0..2 {
                let de = w * (eta[a] - e[a] * r2) / out.trace;
                out.var_e[a] += v * de * de;
            }
        }
    }
    out
}

/// Analytic KSB integrals of an elliptical Gaussian of total flux `flux`
/// and covariance `cov` (pixels²), centred on the weight, for weight scale
/// `sigma_w`, integrated over the whole plane.
///
/// The product of the object and the weight is a Gaussian of covariance
/// C′ = (C⁻¹ + 1/σ_w²)⁻¹ and integral A = F sqrt(det C′ / det C); its moments
/// follow from Isserlis' theorem: with a = C′₁₁, b = C′₂₂, c = C′₁₂,
/// ⟨η₁⟩ = a − b, ⟨η₂⟩ = 2c, ⟨|θ|²⟩ = a + b, ⟨η₁²⟩ = 3a² − 2(ab + 2c²) + 3b²,
/// ⟨η₁η₂⟩ = 6c(a − b), ⟨η₂²⟩ = 4(ab + 2c²), ⟨η₁|θ|²⟩ = 3(a² − b²),
/// ⟨η₂|θ|²⟩ = 6c(a + b).
#[cfg_attr(
    not(test),
    expect(dead_code, reason = "a closed-form reference of unit tests")
)]
pub fn gaussian_integrals(flux: f64, cov: &Mat2, sigma_w: f64) -> KsbIntegrals {
    let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    let inv = [
        [cov[1][1] / det, -cov[0][1] / det],
        [-cov[1][0] / det, cov[0][0] / det],
    ];
    let s2 = sigma_w * sigma_w;
    let m = [
        [inv[0][0] + 1.0 / s2, inv[0][1]],
        [inv[1][0], inv[1][1] + 1.0 / s2],
    ];
    let detm = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    let (a, b, c) = (m[1][1] / detm, m[0][0] / detm, -m[0][1] / detm);
    let detp = a * b - c * c;
    let amp = flux * (detp / det).sqrt();
    let sr2 = amp * (a + b);
    let seta = [amp * (a - b), amp * 2.0 * c];
    let see = [
        [
            amp * (3.0 * a * a - 2.0 * (a * b + 2.0 * c * c) + 3.0 * b * b),
            amp * 6.0 * c * (a - b),
        ],
        [amp * 6.0 * c * (a - b), amp * 4.0 * (a * b + 2.0 * c * c)],
    ];
    let ser = [amp * 3.0 * (a * a - b * b), amp * 6.0 * c * (a + b)];
    let s4 = s2 * s2;
    let mut xsh = [[0.0; 2]; 2];
    let mut xsm = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            let d = if i == j { 1.0 } else { 0.0 };
            xsh[i][j] = 2.0 * sr2 * d - see[i][j] / s2;
            xsm[i][j] = (amp - sr2 / s2) * d + see[i][j] / (4.0 * s4);
        }
    }
    KsbIntegrals {
        sigma_w,
        s0: amp,
        first: [0.0; 2],
        trace: sr2,
        q: seta,
        xsh,
        esh: [0, 1].map(|k| 2.0 * seta[k] - ser[k] / s2),
        xsm,
        esm: [0, 1].map(|k| -seta[k] / s2 + ser[k] / (4.0 * s4)),
        var_e: [0.0; 2],
        var_s0: 0.0,
        clipped: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{covariance, draw_gaussian_sampled, shear_covariance};

    /// A `w` × `h` image of uniform values in [−20, 80).
    fn uniform_image(rng: &mut SimRng, w: usize, h: usize) -> Image {
        let mut img = Image::zeros(w, h);
        for v in &mut img.data {
            *v = rng.random::<f32>() * 100.0 - 20.0;
        }
        img
    }

    /// A random window: centre up to `pad` pixels off the image, scale
    /// 0.5 – 6.5, radius 1 – 5 scales: (xc, yc, σ, radius).
    fn random_window(rng: &mut SimRng, img: &Image, pad: f64) -> (f64, f64, f64, f64) {
        let xc = rng.random::<f64>() * (img.width as f64 + 2.0 * pad) - pad;
        let yc = rng.random::<f64>() * (img.height as f64 + 2.0 * pad) - pad;
        let s = 0.5 + rng.random::<f64>() * 6.0;
        let radius = s * (1.0 + rng.random::<f64>() * 4.0);
        (xc, yc, s, radius)
    }

    #[test]
    fn the_window_moments_twin_is_the_integrals_sums_bit_for_bit() {
        // Random centres (edges included), scales and radii on a noisy
        // image: the twin's four sums equal ksb_integrals' exactly.
        let mut rng = SeedKey::base(7, 0, Stream::Noise).rng();
        let img = uniform_image(&mut rng, 61, 47);
        for _ in 0..500 {
            let (xc, yc, s, radius) = random_window(&mut rng, &img, 5.0);
            let twin = window_moments_slow(&img, xc, yc, s, radius);
            let full = ksb_integrals(&img, xc, yc, s, radius, None);
            assert_eq!(twin.s0.to_bits(), full.s0.to_bits());
            assert_eq!(twin.first[0].to_bits(), full.first[0].to_bits());
            assert_eq!(twin.first[1].to_bits(), full.first[1].to_bits());
            assert_eq!(twin.trace.to_bits(), full.trace.to_bits());
            assert_eq!(twin.clipped, full.clipped);
        }
    }

    #[test]
    fn window_moments_agree_with_their_per_pixel_twin() {
        // Factored row sums against the per-pixel sums: random centres (off
        // the image too), scales and radii, sky-like values with sources
        // and negative pixels, two NaN pixels. Each sum within 1e-13 of
        // Σ W |I| (× radius, × radius² for the first moments and the
        // trace); a window holding a NaN pixel, or with a NaN centre or
        // radius, is NaN in both; the same clipping.
        let mut rng = SeedKey::base(8, 0, Stream::Test).rng();
        let w = 53;
        let mut img = uniform_image(&mut rng, w, 44);
        draw_gaussian_sampled(&mut img, 20.3, 25.8, 3e5, &covariance(2.0, [0.2, 0.1]));
        let mut abs = img.clone();
        for v in &mut abs.data {
            *v = v.abs();
        }
        img.data[17 * w + 30] = f32::NAN;
        img.data[5 * w + 8] = f32::NAN;
        let (mut finite, mut nan, mut worst) = (0, 0, 0.0f64);
        for _ in 0..2000 {
            let (xc, yc, s, radius) = random_window(&mut rng, &img, 10.0);
            let fast = window_moments(&img, xc, yc, s, radius);
            let slow = window_moments_slow(&img, xc, yc, s, radius);
            assert_eq!(fast.clipped, slow.clipped);
            if slow.s0.is_nan() {
                assert!(fast.s0.is_nan() && fast.first[0].is_nan() && fast.trace.is_nan());
                nan += 1;
                continue;
            }
            let scale = window_moments_slow(&abs, xc, yc, s, radius).s0;
            if scale > 0.0 {
                finite += 1;
            }
            for (a, b, r) in [
                (fast.s0, slow.s0, 1.0),
                (fast.first[0], slow.first[0], radius),
                (fast.first[1], slow.first[1], radius),
                (fast.trace, slow.trace, radius * radius),
            ] {
                let d = (a - b).abs() / (scale * r).max(1e-300);
                worst = worst.max(d);
                assert!(d <= 1e-13, "{fast:?} {slow:?} scale {scale}");
            }
        }
        // Both kinds of window were met; the sums did differ in rounding.
        assert!(finite > 1000 && nan > 20, "{finite} {nan}");
        assert!(worst > 0.0);
        for (xc, yc, r) in [(f64::NAN, 20.0, 6.0), (20.0, 20.0, f64::NAN)] {
            let (fast, slow) = (
                window_moments(&img, xc, yc, 2.0, r),
                window_moments_slow(&img, xc, yc, 2.0, r),
            );
            assert!(fast.s0.is_nan() && slow.s0.is_nan());
            assert_eq!(fast.clipped, slow.clipped);
        }
    }

    use rand::RngExt;
    use stepsim_contract::seed::{SeedKey, SimRng, Stream};

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    fn assert_shapes_close(a: &KsbShape, b: &KsbShape, tol: f64) {
        for i in 0..2 {
            assert!(close(a.e[i], b.e[i], tol), "e{i}: {} vs {}", a.e[i], b.e[i]);
            for j in 0..2 {
                assert!(
                    close(a.psm[i][j], b.psm[i][j], tol),
                    "psm{i}{j}: {} vs {}",
                    a.psm[i][j],
                    b.psm[i][j]
                );
                assert!(
                    close(a.psh[i][j], b.psh[i][j], tol),
                    "psh{i}{j}: {} vs {}",
                    a.psh[i][j],
                    b.psh[i][j]
                );
            }
        }
    }

    #[test]
    fn fast_sums_equal_the_reference_on_a_noisy_image() {
        let mut img = Image::zeros(41, 37);
        let mut rng = SeedKey::base(7, 0, Stream::Test).rng();
        for v in &mut img.data {
            *v = rng.random_range(-5.0f32..20.0);
        }
        let noise = Some(PixelNoise {
            background_var: 9.0,
            poisson: true,
        });
        // Inside and clipped by the edge.
        for (xc, yc, s) in [(20.3, 18.7, 3.1), (2.2, 30.5, 2.0)] {
            let a = ksb_integrals(&img, xc, yc, s, 4.0 * s, noise);
            let b = ksb_integrals_slow(&img, xc, yc, s, 4.0 * s, noise);
            let rel = |x: f64, y: f64| (x - y).abs() / (1e-300 + x.abs().max(y.abs()));
            assert_eq!(a.clipped, b.clipped);
            assert!(rel(a.s0, b.s0) < 1e-11);
            assert!(rel(a.trace, b.trace) < 1e-11);
            assert!(rel(a.var_s0, b.var_s0) < 1e-11);
            for k in 0..2 {
                assert!(rel(a.var_e[k], b.var_e[k]) < 1e-9, "{a:?} {b:?}");
                assert!(rel(a.first[k], b.first[k]) < 1e-9);
            }
            assert_shapes_close(&a.shape().unwrap(), &b.shape().unwrap(), 1e-9);
        }
    }

    #[test]
    fn sampled_gaussian_matches_analytic_moments() {
        // A point-sampled Gaussian with σ ≥ 2 px sums like its integral to
        // ~exp(−2π²σ′²), far below 1e-9; the window of 8 r_g loses < 1e-12;
        // the f32 pixels round at 6e-8. Tolerance 1e-6 absolute on e, P^sm, P^sh.
        for (sigma, e, rg) in [
            (2.5, [0.3, -0.2], 2.5),
            (3.0, [0.0, 0.5], 2.0),
            (2.0, [0.6, 0.1], 4.0),
        ] {
            let cov = covariance(sigma, e);
            let mut img = Image::zeros(81, 81);
            draw_gaussian_sampled(&mut img, 40.2, 39.7, 1000.0, &cov);
            let m = ksb_integrals(&img, 40.2, 39.7, rg, 8.0 * rg, None);
            let a = gaussian_integrals(1000.0, &cov, rg);
            assert!((m.s0 - a.s0).abs() < 1e-6 * a.s0);
            assert_shapes_close(&m.shape().unwrap(), &a.shape().unwrap(), 1e-6);
        }
    }

    #[test]
    fn round_gaussian_polarisabilities_have_their_closed_form() {
        // Round Gaussian of σ = r_g: C′ = (r_g²/2) I, A = 1/2, T = A r_g²,
        // Σ W I η₁² = 4 A (r_g²/2)² = A r_g⁴. Hence
        // P^sh_11 = (2T − A r_g⁴/r_g²)/T = 1 and
        // P^sm_11 = (A − T/r_g² + A r_g⁴/4r_g⁴)/T = 1/(4 r_g²).
        let rg = 2.7;
        let s = gaussian_integrals(1.0, &[[rg * rg, 0.0], [0.0, rg * rg]], rg)
            .shape()
            .unwrap();
        assert!((s.psh[0][0] - 1.0).abs() < 1e-12 && (s.psh[1][1] - 1.0).abs() < 1e-12);
        assert!((s.psm[0][0] - 0.25 / (rg * rg)).abs() < 1e-12);
        assert!(s.psh[0][1].abs() < 1e-15 && s.e[0].abs() < 1e-15);
    }

    #[test]
    fn shear_polarisability_is_the_response_to_a_shear() {
        // δe = P^sh γ by central finite differences of the analytic moments of
        // a sheared Gaussian (SPEC §1 shear). Tolerance 1e-7 (step 1e-5).
        let h = 1e-5;
        for (sigma, e, rg) in [
            (2.0, [0.2, 0.1], 2.0),
            (3.0, [-0.4, 0.3], 2.0),
            (1.5, [0.0, 0.0], 3.0),
        ] {
            let cov = covariance(sigma, e);
            let base = gaussian_integrals(1.0, &cov, rg).shape().unwrap();
            for b in 0..2 {
                let mut g = [0.0; 2];
                g[b] = h;
                let plus = gaussian_integrals(1.0, &shear_covariance(&cov, g), rg)
                    .shape()
                    .unwrap();
                g[b] = -h;
                let minus = gaussian_integrals(1.0, &shear_covariance(&cov, g), rg)
                    .shape()
                    .unwrap();
                for a in 0..2 {
                    let de = (plus.e[a] - minus.e[a]) / (2.0 * h);
                    assert!(
                        (de - base.psh[a][b]).abs() < 1e-7,
                        "P^sh[{a}][{b}] = {} but δe/δγ = {de}",
                        base.psh[a][b]
                    );
                }
            }
        }
    }

    #[test]
    fn smear_polarisability_is_the_response_to_an_anisotropic_smear() {
        // Convolution with a kernel of traceless covariance ½[[p1, p2], [p2, −p1]]
        // adds it to the Gaussian's covariance; δe = P^sm p. Tolerance 1e-7.
        let h = 1e-5;
        for (sigma, e, rg) in [
            (2.0, [0.2, 0.1], 2.0),
            (3.0, [-0.4, 0.3], 2.5),
            (1.5, [0.0, 0.0], 3.0),
        ] {
            let cov = covariance(sigma, e);
            let base = gaussian_integrals(1.0, &cov, rg).shape().unwrap();
            for b in 0..2 {
                let smear = |sign: f64| {
                    let mut p = [0.0; 2];
                    p[b] = sign * h;
                    let c = [
                        [cov[0][0] + 0.5 * p[0], cov[0][1] + 0.5 * p[1]],
                        [cov[1][0] + 0.5 * p[1], cov[1][1] - 0.5 * p[0]],
                    ];
                    gaussian_integrals(1.0, &c, rg).shape().unwrap()
                };
                let (plus, minus) = (smear(1.0), smear(-1.0));
                for a in 0..2 {
                    let de = (plus.e[a] - minus.e[a]) / (2.0 * h);
                    assert!(
                        (de - base.psm[a][b]).abs() < 1e-7 * (1.0 + base.psm[a][b].abs()),
                        "P^sm[{a}][{b}] = {} but δe/δp = {de}",
                        base.psm[a][b]
                    );
                }
            }
        }
    }

    #[test]
    fn noise_of_e_matches_the_scatter_of_noisy_measurements() {
        // 400 noise realisations of one Gaussian: the predicted σ_e agrees
        // with the measured scatter within 12 % (the 2σ sampling error of an
        // rms from 400 draws is 7 %).
        let cov = covariance(2.5, [0.2, 0.0]);
        let mut clean = Image::zeros(41, 41);
        draw_gaussian_sampled(&mut clean, 20.0, 20.0, 3000.0, &cov);
        let noise = PixelNoise {
            background_var: 25.0,
            poisson: false,
        };
        let pred = ksb_integrals(&clean, 20.0, 20.0, 2.5, 10.0, Some(noise))
            .shape()
            .unwrap();
        let mut rng = SeedKey::base(3, 0, Stream::Test).rng();
        let mut e1 = Vec::new();
        for _ in 0..400 {
            let mut img = clean.clone();
            for v in &mut img.data {
                let n: f64 = rng.sample(rand_distr::StandardNormal);
                *v += (5.0 * n) as f32;
            }
            e1.push(
                ksb_integrals(&img, 20.0, 20.0, 2.5, 10.0, None)
                    .shape()
                    .unwrap()
                    .e[0],
            );
        }
        let mean = e1.iter().sum::<f64>() / e1.len() as f64;
        let sd =
            (e1.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (e1.len() - 1) as f64).sqrt();
        assert!(
            (sd / pred.sigma_e[0] - 1.0).abs() < 0.12,
            "{sd} vs {}",
            pred.sigma_e[0]
        );
    }
}
