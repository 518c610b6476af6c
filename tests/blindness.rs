//! The blind release tells nothing but its pixels: file metadata does not
//! follow the datasets, nothing public depends on the seed except the pixels
//! (and the ids and checksums keyed by it), and a run without a seed draws a
//! secret one that only its private half records and reproduces.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::common;
use common::{files, run};

fn generate(dir: &Path, config: &str, out: &str, extra: &[&str]) -> String {
    let mut args = vec!["generate", "--config", config, "--out", out];
    args.extend_from_slice(extra);
    let o = run(&args, dir);
    assert!(
        o.status.success(),
        "generate {config} {out} {extra:?} failed"
    );
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// 6 Gaussian PSFs × 5 shears = 30 datasets of `n` tiny images.
fn thirty_datasets(n_images: u32) -> String {
    let psfs: Vec<String> = (0..6)
        .map(|i| {
            format!(
                r#"{{"name": "p{i}", "model": "gaussian", "fwhm_arcsec": {}}}"#,
                0.7 + 0.1 * f64::from(i)
            )
        })
        .collect();
    format!(
        r#"{{
  "image": {{"width_px": 32, "height_px": 32, "n_images": {n_images}, "margin_arcsec": 1.0}},
  "population": {{"galaxies": {{"mag_faint": 23.0}}}},
  "psfs": [{}],
  "shears": [{{"g1": 0.0}}, {{"g1": 0.005}}, {{"g1": 0.01}}, {{"g1": 0.05}}, {{"g1": 0.1}}]
}}"#,
        psfs.join(", ")
    )
}

/// Spearman's rank correlation (ties get their mean rank); 0 when either
/// side is constant (e.g. every time stamp equal).
fn spearman(x: &[f64], y: &[f64]) -> f64 {
    fn ranks(v: &[f64]) -> Vec<f64> {
        let mut idx: Vec<usize> = (0..v.len()).collect();
        idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
        let mut r = vec![0.0; v.len()];
        let mut i = 0;
        while i < idx.len() {
            let mut j = i;
            while j + 1 < idx.len() && v[idx[j + 1]] == v[idx[i]] {
                j += 1;
            }
            for &k in &idx[i..=j] {
                r[k] = (i + j) as f64 / 2.0;
            }
            i = j + 1;
        }
        r
    }
    let (rx, ry) = (ranks(x), ranks(y));
    let n = x.len() as f64;
    let (mx, my) = (rx.iter().sum::<f64>() / n, ry.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in rx.iter().zip(&ry) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx == 0.0 || syy == 0.0 {
        0.0
    } else {
        sxy / (sxx * syy).sqrt()
    }
}

#[test]
fn spearman_of_known_orders() {
    let a = [1.0, 2.0, 3.0, 4.0, 5.0];
    assert_eq!(spearman(&a, &a), 1.0);
    assert_eq!(spearman(&a, &[5.0, 4.0, 3.0, 2.0, 1.0]), -1.0);
    assert_eq!(spearman(&a, &[7.0; 5]), 0.0);
    // d² = 0 + 1 + 1 + 0 + 0 → 1 − 6·2/(5·24) = 0.9
    assert!((spearman(&a, &[1.0, 3.0, 2.0, 4.0, 5.0]) - 0.9).abs() < 1e-12);
}

/// The metadata orderings of a path: mtime, ctime, inode (as numbers).
fn metadata_keys(p: &Path) -> [f64; 3] {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::symlink_metadata(p).unwrap();
    [
        m.mtime() as f64 * 1e9 + m.mtime_nsec() as f64,
        m.ctime() as f64 * 1e9 + m.ctime_nsec() as f64,
        m.ino() as f64,
    ]
}

fn listing(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect()
}

#[test]
fn metadata_of_public_does_not_follow_the_datasets() {
    // Dataset order is PSF-major with shears ascending: a metadata order that
    // follows it tells which datasets share a PSF and which has which shear.
    // Bounds: |ρ| < 0.6 over the 30 dataset directories (a random order has
    // σ = 1/√29 = 0.19) and < 0.4 for the images, averaged over the 4 base
    // fields (σ = 0.09). Before the fix mtime, ctime and inode gave ρ = 1.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), thirty_datasets(4)).unwrap();
    generate(
        d,
        "c.json",
        "run",
        &["--threads", "2", "--set", "run.seed=31415"],
    );
    let public = d.join("run/public");
    let datasets: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("run/private/datasets.json")).unwrap())
            .unwrap();
    let datasets = datasets["datasets"].as_array().unwrap();
    assert_eq!(datasets.len(), 30);
    // Canonical index of each dataset and image.
    let mut dataset_index: BTreeMap<String, f64> = BTreeMap::new();
    let mut image_place: BTreeMap<String, (f64, u64)> = BTreeMap::new();
    for (i, ds) in datasets.iter().enumerate() {
        dataset_index.insert(ds["dataset"].as_str().unwrap().into(), i as f64);
        for im in ds["images"].as_array().unwrap() {
            image_place.insert(
                format!("{}.fits", im["image"].as_str().unwrap()),
                (i as f64, im["field"].as_u64().unwrap()),
            );
        }
    }
    assert_eq!(image_place.len(), 120);
    // Listing order: dataset directories as listed, images as listed in them.
    let names = ["mtime", "ctime", "inode", "listing"];
    let mut dir_keys: Vec<(f64, [f64; 4])> = Vec::new();
    let mut image_keys: Vec<(f64, u64, [f64; 4])> = Vec::new();
    let mut position = 0.0;
    for (k, sub) in listing(&public)
        .into_iter()
        .filter(|p| p.is_dir())
        .enumerate()
    {
        let name = sub.file_name().unwrap().to_string_lossy().into_owned();
        let [m, c, i] = metadata_keys(&sub);
        dir_keys.push((dataset_index[&name], [m, c, i, k as f64]));
        for f in listing(&sub) {
            let (index, field) =
                image_place[&f.file_name().unwrap().to_string_lossy().into_owned()];
            let [m, c, i] = metadata_keys(&f);
            image_keys.push((index, field, [m, c, i, position]));
            position += 1.0;
        }
    }
    assert_eq!((dir_keys.len(), image_keys.len()), (30, 120));
    // Every file and directory of public/ carries one time stamp.
    let [t0, _, _] = metadata_keys(&public);
    assert!(dir_keys.iter().all(|(_, k)| k[0] == t0));
    assert!(image_keys.iter().all(|(_, _, k)| k[0] == t0));
    for f in ["README.md", "manifest.json"] {
        assert_eq!(metadata_keys(&public.join(f))[0], t0, "{f}");
    }
    for (m, name) in names.iter().enumerate() {
        let x: Vec<f64> = dir_keys.iter().map(|(i, _)| *i).collect();
        let y: Vec<f64> = dir_keys.iter().map(|(_, k)| k[m]).collect();
        let rho = spearman(&x, &y);
        eprintln!("dataset directories, {name}: rho = {rho:+.3}");
        assert!(
            rho.abs() < 0.6,
            "dataset directories by {name}: rho = {rho}"
        );
        let mut per_field = Vec::new();
        for field in 0..4 {
            let of: Vec<_> = image_keys.iter().filter(|k| k.1 == field).collect();
            let x: Vec<f64> = of.iter().map(|k| k.0).collect();
            let y: Vec<f64> = of.iter().map(|k| k.2[m]).collect();
            per_field.push(spearman(&x, &y));
        }
        let mean = per_field.iter().sum::<f64>() / 4.0;
        eprintln!("images within a base field, {name}: rho = {per_field:+.3?}, mean {mean:+.3}");
        assert!(mean.abs() < 0.4, "images by {name}: rho {per_field:?}");
    }
}

/// The FITS header of a file (up to and including the END card).
fn header(bytes: &[u8]) -> Vec<u8> {
    for block in 0..bytes.len() / 2880 {
        for card in 0..36 {
            let at = block * 2880 + card * 80;
            if bytes[at..at + 80].starts_with(b"END     ") {
                return bytes[..at + 80].to_vec();
            }
        }
    }
    panic!("no END card");
}

/// (dataset index, field, rotated) -> (dataset id, image id), from
/// `private/datasets.json`.
fn ids(run: &Path) -> BTreeMap<(usize, u64, bool), (String, String)> {
    let d: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("private/datasets.json")).unwrap()).unwrap();
    let mut out = BTreeMap::new();
    for (i, ds) in d["datasets"].as_array().unwrap().iter().enumerate() {
        for im in ds["images"].as_array().unwrap() {
            out.insert(
                (
                    i,
                    im["field"].as_u64().unwrap(),
                    im["rotated"].as_bool().unwrap(),
                ),
                (
                    ds["dataset"].as_str().unwrap().to_string(),
                    im["image"].as_str().unwrap().to_string(),
                ),
            );
        }
    }
    out
}

const SMALL: &str = r#"{
  "run": {"name": "small"},
  "image": {"width_px": 48, "height_px": 40, "n_images": 2, "margin_arcsec": 1.0},
  "population": {"rotated_pairs": true, "galaxies": {"mag_faint": 23.0}},
  "psfs": [{"name": "a", "model": "gaussian"}, {"name": "b", "model": "moffat", "beta": 3.0}],
  "shears": [{"g1": 0.0}, {"g1": 0.03, "g2": -0.01}]
}"#;

#[test]
fn nothing_public_depends_on_the_seed_but_pixels_ids_and_checksums() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), SMALL).unwrap();
    generate(d, "c.json", "s1", &["--set", "run.seed=1"]);
    generate(d, "c.json", "s2", &["--set", "run.seed=2"]);
    let (a, b) = (d.join("s1"), d.join("s2"));
    let read = |p: PathBuf| std::fs::read(p).unwrap();
    assert!(read(a.join("public/README.md")) == read(b.join("public/README.md")));
    let (ia, ib) = (ids(&a), ids(&b));
    assert_eq!(ia.len(), 16);
    assert_eq!(ia.keys().collect::<Vec<_>>(), ib.keys().collect::<Vec<_>>());
    let mut pixels_differ = 0;
    for (k, (da, xa)) in &ia {
        let (db, xb) = &ib[k];
        assert_ne!(xa, xb, "the seed keys the ids");
        let fa = read(a.join(format!("public/{da}/{xa}.fits")));
        let fb = read(b.join(format!("public/{db}/{xb}.fits")));
        assert_eq!(fa.len(), fb.len(), "{k:?}: sizes");
        assert!(header(&fa) == header(&fb), "{k:?}: FITS headers differ");
        pixels_differ += usize::from(fa != fb);
    }
    assert_eq!(pixels_differ, 16);
    // The manifests have one structure: the same keys and instrument facts,
    // and the same entries once ids and checksums are blanked.
    let manifest = |run: &Path, ids: &BTreeMap<_, (String, String)>| {
        let mut m: serde_json::Value =
            serde_json::from_slice(&read(run.join("public/manifest.json"))).unwrap();
        let by_image: BTreeMap<&str, &(usize, u64, bool)> =
            ids.iter().map(|(k, (_, i))| (i.as_str(), k)).collect();
        let mut entries: Vec<String> = m["images"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| {
                let mut keys: Vec<&String> = e.as_object().unwrap().keys().collect();
                keys.sort();
                format!("{:?} {keys:?}", by_image[e["image"].as_str().unwrap()])
            })
            .collect();
        entries.sort();
        m["images"] = serde_json::json!(entries);
        m
    };
    assert_eq!(manifest(&a, &ia), manifest(&b, &ib));
}

#[test]
fn a_run_without_seed_draws_a_secret_one_and_its_private_half_reproduces_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), SMALL).unwrap();
    let err = generate(d, "c.json", "a", &[]);
    assert!(
        err.contains("drew a secret seed") && !err.contains("warning"),
        "{err}"
    );
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("a/private/config.json")).unwrap()).unwrap();
    let seed = config["run"]["seed"]
        .as_u64()
        .expect("the drawn seed is recorded");
    // Nothing public holds it.
    for (path, bytes) in files(&d.join("a/public")) {
        let text = String::from_utf8_lossy(&bytes);
        assert!(!text.contains(&seed.to_string()), "{}", path.display());
    }
    // Another run of the same config draws another seed: other ids.
    generate(d, "c.json", "b", &[]);
    assert_ne!(ids(&d.join("a")), ids(&d.join("b")));
    // Rerunning the seedless config into its run continues it (adopts the seed).
    let err = generate(d, "c.json", "a", &[]);
    assert!(
        err.contains("continuing the run") && err.contains("0 images written, 16 already"),
        "{err}"
    );
    // The private config reproduces the run byte for byte (with a warning:
    // the seed is now given).
    let err = generate(d, "a/private/config.json", "c", &[]);
    assert!(err.contains("warning: run.seed is given"), "{err}");
    let (fa, fc) = (files(&d.join("a")), files(&d.join("c")));
    assert_eq!(fa.len(), 16 * 3 + 5 + 2, "{:?}", fa.keys());
    assert_eq!(fa.keys().collect::<Vec<_>>(), fc.keys().collect::<Vec<_>>());
    for (k, v) in &fa {
        assert!(fc[k] == *v, "{} differs", k.display());
    }
}

/// The header cards of a FITS file's primary HDU, grouped by keyword (a
/// keyword that repeats, e.g. `COMMENT`, keeps every card in order). The
/// whole 80-character card is the value: a comment that varied would tell
/// as much as a value.
fn cards(bytes: &[u8]) -> BTreeMap<String, String> {
    let mut out: BTreeMap<String, String> = BTreeMap::new();
    for card in header(bytes).chunks(80) {
        let text = String::from_utf8_lossy(card).into_owned();
        out.entry(text[..8].trim_end().to_string())
            .or_default()
            .push_str(&text);
    }
    out
}

/// The partition of `0..n` joined by shared values: items `i` and `j` are in
/// one block when some value is in both `values[i]` and `values[j]`, or
/// through a chain of such items. Blocks as sorted lists, sorted.
fn partition(values: &[Vec<String>]) -> Vec<Vec<usize>> {
    let n = values.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut first: BTreeMap<&str, usize> = BTreeMap::new();
    for (i, vs) in values.iter().enumerate() {
        for v in vs {
            let j = *first.entry(v.as_str()).or_insert(i);
            let (a, b) = (root(&mut parent, i), root(&mut parent, j));
            parent[a] = b;
        }
    }
    let mut blocks: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for i in 0..n {
        let r = root(&mut parent, i);
        blocks.entry(r).or_default().push(i);
    }
    let mut out: Vec<Vec<usize>> = blocks.into_values().collect();
    out.sort();
    out
}

/// The labellings (of `labels`, by name) that a partition gives away: it
/// tells something about a labelling when it is neither one block nor all
/// singletons and one of its blocks of two or more items has one label.
fn given_away(blocks: &[Vec<usize>], labels: &[(&str, Vec<String>)]) -> Vec<String> {
    let n: usize = blocks.iter().map(Vec::len).sum();
    if blocks.len() == 1 || blocks.len() == n {
        return Vec::new();
    }
    labels
        .iter()
        .filter(|(_, l)| {
            blocks
                .iter()
                .any(|b| b.len() >= 2 && b.iter().all(|&i| l[i] == l[b[0]]))
        })
        .map(|(name, _)| (*name).to_string())
        .collect()
}

#[test]
fn partition_and_what_it_gives_away_on_known_cases() {
    let v = |s: &[&str]| s.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    // 0–1 share "a", 1–2 share "b": one chain; 3 alone.
    assert_eq!(
        partition(&[v(&["a"]), v(&["a", "b"]), v(&["b"]), v(&["c"])]),
        vec![vec![0, 1, 2], vec![3]]
    );
    let part = ("part", v(&["p", "p", "h", "h"]));
    let psf = ("psf", v(&["x", "y", "x", "y"]));
    let labels = [part, psf];
    assert_eq!(
        given_away(&[vec![0, 1], vec![2, 3]], &labels),
        vec!["part".to_string()]
    );
    assert_eq!(
        given_away(&[vec![0, 2], vec![1, 3]], &labels),
        vec!["psf".to_string()]
    );
    assert!(given_away(&[vec![0, 1, 2, 3]], &labels).is_empty());
    assert!(given_away(&[vec![0], vec![1], vec![2], vec![3]], &labels).is_empty());
}

#[test]
fn no_header_keyword_groups_datasets_by_part_psf_or_shear() {
    // A challenge run: 30 public datasets (6 PSFs × 5 shears) on one base
    // field and 30 held-out ones (the same PSFs, random shears) on the
    // other, each with the field's rotated twin, as `--set challenge.holdout_fields=1` makes of
    // configs/step1-mini.json. Before the fix every image's CRVAL1 was its
    // base field's, so grouping the public images by CRVAL1 gave two groups
    // of 30 datasets: exactly the two parts (issue #23).
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), thirty_datasets(2)).unwrap();
    generate(
        d,
        "c.json",
        "run",
        &[
            "--set",
            "run.seed=2718",
            "--set",
            "challenge.holdout_fields=1",
            "--set",
            "population.rotated_pairs=true",
        ],
    );
    let run = d.join("run");
    let datasets: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("private/datasets.json")).unwrap()).unwrap();
    let datasets = datasets["datasets"].as_array().unwrap();
    assert_eq!(datasets.len(), 60);
    let mut index: BTreeMap<String, usize> = BTreeMap::new();
    let (mut part, mut psf, mut shear) = (Vec::new(), Vec::new(), Vec::new());
    for (i, ds) in datasets.iter().enumerate() {
        index.insert(ds["dataset"].as_str().unwrap().into(), i);
        part.push(ds["part"].as_str().unwrap_or("public").to_string());
        psf.push(ds["psf_id"].to_string());
        shear.push(format!("{} {}", ds["g1"], ds["g2"]));
    }
    assert_eq!(part.iter().filter(|p| *p == "holdout").count(), 30);
    let labels = [("part", part), ("psf", psf), ("shear", shear)];
    // Every public image's header cards, by dataset and keyword.
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("public/manifest.json")).unwrap()).unwrap();
    let images = manifest["images"].as_array().unwrap();
    assert_eq!(images.len(), 120);
    let mut by_dataset: Vec<Vec<BTreeMap<String, String>>> = vec![Vec::new(); 60];
    let mut keywords = std::collections::BTreeSet::new();
    for im in images {
        let bytes = std::fs::read(run.join("public").join(im["file"].as_str().unwrap())).unwrap();
        let c = cards(&bytes);
        keywords.extend(c.keys().cloned());
        by_dataset[index[im["dataset"].as_str().unwrap()]].push(c);
    }
    for k in [
        "CRVAL1", "CRVAL2", "CRPIX1", "CD1_1", "GAIN", "MAGZERO", "NAXIS1",
    ] {
        assert!(keywords.contains(k), "no {k} in {keywords:?}");
    }
    let mut leaks = Vec::new();
    for k in &keywords {
        let values: Vec<Vec<String>> = by_dataset
            .iter()
            .map(|imgs| {
                imgs.iter()
                    .map(|c| c.get(k).cloned().unwrap_or_else(|| "<absent>".into()))
                    .collect()
            })
            .collect();
        let blocks = partition(&values);
        let sizes: Vec<usize> = blocks.iter().map(Vec::len).collect();
        let away = given_away(&blocks, &labels);
        eprintln!(
            "{k}: {} blocks of {sizes:?}; gives away {away:?}",
            blocks.len()
        );
        if !away.is_empty() {
            leaks.push(format!("{k} ({} blocks) gives away {away:?}", blocks.len()));
        }
    }
    assert!(
        leaks.is_empty(),
        "header keywords group datasets: {leaks:?}"
    );
}
