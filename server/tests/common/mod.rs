//! The challenge run the server's tests share: declared once in
//! `tests/integration.rs`, used by each test module as `crate::common`.
#![allow(dead_code)]

use std::path::Path;
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, challenge_run, submission_text};

/// A challenge run written to `dir/run/private`: the public part (2 PSFs ×
/// 2 shears on fields 0-1) and the held-out part (other shears on fields
/// 2-3). Returns the whole run and its held-out part.
pub fn write_run(dir: &Path) -> (SynthRun, SynthRun) {
    write_run_of_fields(dir, 2)
}

/// [`write_run`] with `fields` base fields in each part.
pub fn write_run_of_fields(dir: &Path, fields: u32) -> (SynthRun, SynthRun) {
    let mut spec = SynthSpec::small(fields);
    spec.psfs.truncate(2);
    spec.shears = vec![(0.0, 0.0), (0.05, 0.0)];
    let (_, held, all) = challenge_run(&spec, &[(0.0371, -0.0523), (-0.0617, 0.0289)], 7);
    all.write(&dir.join("run/private")).unwrap();
    (all, held)
}

/// [`write_run`] with `readme` as the participants' README in `dir/run/public`.
pub fn write_run_with_readme(dir: &Path, readme: &str) -> (SynthRun, SynthRun) {
    let run = write_run(dir);
    std::fs::create_dir_all(dir.join("run/public")).unwrap();
    std::fs::write(dir.join("run/public/README.md"), readme).unwrap();
    run
}

/// A catalogue of the whole run: galaxies with multiplicative bias `m` and
/// additive `c` on e1, no stars.
pub fn catalogue_mc(all: &SynthRun, m: f64, c: f64) -> String {
    let rows = all.submission(&|t, _| {
        (!t.is_star()).then_some(((1.0 + m) * t.e1 + c, (1.0 + m) * t.e2, 1.0))
    });
    submission_text(&all.index(), &rows)
}

/// A catalogue of the whole run: galaxies with multiplicative bias `m`,
/// no stars.
pub fn catalogue(all: &SynthRun, m: f64) -> String {
    let rows =
        all.submission(&|t, _| (!t.is_star()).then_some(((1.0 + m) * t.e1, (1.0 + m) * t.e2, 1.0)));
    submission_text(&all.index(), &rows)
}

/// Writes the images and `manifest.json` of `all` under `dir/run/public`
/// (made-up bytes, one file per image, `<dataset>/<image>.fits` as
/// `stepsim generate` names them); a README already there is kept. Returns
/// each listed file (manifest, README when present, images) with its bytes.
pub fn write_public(dir: &Path, all: &SynthRun) -> Vec<(String, Vec<u8>)> {
    use sha2::Digest;
    let public = dir.join("run/public");
    let mut images = Vec::new();
    let mut files = Vec::new();
    for (k, d) in all.datasets.datasets.iter().enumerate() {
        for (j, im) in d.images.iter().enumerate() {
            let file = format!("{}/{}.fits", d.dataset, im.image);
            let bytes: Vec<u8> = (0..700 + 37 * k + 5 * j)
                .map(|i| (i * 7 + k + 3 * j) as u8)
                .collect();
            std::fs::create_dir_all(public.join(&d.dataset)).unwrap();
            std::fs::write(public.join(&file), &bytes).unwrap();
            images.push(serde_json::json!({
                "image": im.image, "dataset": d.dataset, "file": file,
                "sha256": stepsim_contract::digest::hex(&sha2::Sha256::digest(&bytes)),
            }));
            files.push((file, bytes));
        }
    }
    let manifest = serde_json::json!({
        "format": "stepsim-manifest-1",
        "instrument": {"width_px": 64, "height_px": 64, "pixel_scale_arcsec": 0.2,
            "gain_e_per_adu": 4.0, "read_noise_e": 5.0, "saturation_adu": 65535.0,
            "exposure_s": 3600.0, "zeropoint_mag": 26.0},
        "images": images,
    });
    let text = serde_json::to_string_pretty(&manifest).unwrap();
    std::fs::write(public.join("manifest.json"), &text).unwrap();
    let mut all_files = vec![("manifest.json".to_string(), text.into_bytes())];
    if let Ok(readme) = std::fs::read(public.join("README.md")) {
        all_files.push(("README.md".to_string(), readme));
    }
    all_files.extend(files);
    all_files
}

/// The store the tests run on: a fresh PostgreSQL database on the server
/// that `STEPSIM_TEST_POSTGRES` names (a URL whose user may create
/// databases, e.g. `postgres://postgres@127.0.0.1:5433/postgres`; set by
/// `tests/all.sh` for the second run of these tests), else `None`: the
/// state directory's SQLite file.
pub async fn test_store() -> Option<stepsim_server::StoreUrl> {
    let admin = std::env::var("STEPSIM_TEST_POSTGRES").ok()?;
    Some(fresh_database(&admin).await)
}

/// Creates an empty database on the server of `admin` and returns its URL.
pub async fn fresh_database(admin: &str) -> stepsim_server::StoreUrl {
    let (client, conn) = tokio_postgres::connect(admin, tokio_postgres::NoTls)
        .await
        .unwrap_or_else(|e| panic!("STEPSIM_TEST_POSTGRES={admin}: {e}"));
    tokio::spawn(conn);
    let mut b = [0u8; 8];
    getrandom::fill(&mut b).unwrap();
    let name = format!(
        "stepsim_t_{}",
        b.iter().map(|x| format!("{x:02x}")).collect::<String>()
    );
    client
        .batch_execute(&format!("CREATE DATABASE {name}"))
        .await
        .unwrap();
    let (base, _) = admin.rsplit_once('/').expect("a URL with a database");
    stepsim_server::StoreUrl::Postgres(format!("{base}/{name}"))
}

/// `Challenge::init` on the tests' store ([`test_store`]).
pub async fn init(
    run: &Path,
    state: &Path,
    quota: u32,
    no_holdout: bool,
) -> Result<stepsim_server::Challenge, stepsim_server::ChallengeError> {
    let store = test_store().await;
    stepsim_server::Challenge::init_with_store(run, state, quota, no_holdout, store.as_ref()).await
}

/// The lease the tests' own scoring loops take jobs with.
pub fn lease() -> stepsim_server::Lease {
    stepsim_server::Lease {
        worker: "test".into(),
        seconds: 600,
    }
}

/// Everything the challenge's store holds, as text: the SQLite file's
/// bytes, or every row of every table of its PostgreSQL database (for
/// tests that a secret is never stored).
pub async fn store_text(state: &Path) -> String {
    match std::fs::read_to_string(state.join(stepsim_server::STORE_FILE)) {
        Ok(url) => {
            let (client, conn) = tokio_postgres::connect(url.trim(), tokio_postgres::NoTls)
                .await
                .unwrap();
            tokio::spawn(conn);
            let mut text = String::new();
            for table in ["meta", "teams", "submissions", "format_failures", "scores"] {
                for row in client
                    .query(&format!("SELECT row_to_json(x)::text FROM {table} x"), &[])
                    .await
                    .unwrap()
                {
                    text.push_str(row.get::<_, &str>(0));
                    text.push('\n');
                }
            }
            text
        }
        // The file and its write-ahead log (WAL mode: recent writes are
        // there until a checkpoint).
        Err(_) => ["challenge.db", "challenge.db-wal"]
            .iter()
            .filter_map(|f| std::fs::read(state.join(f)).ok())
            .map(|b| String::from_utf8_lossy(&b).into_owned())
            .collect(),
    }
}

/// Scores every queued job of the challenge in `state` now, as a worker
/// does (claimed under [`lease`], recorded as worker "test" at time 0).
pub async fn score_queue(state: &Path) {
    let ch = stepsim_server::Challenge::open(state).await.unwrap();
    while let Some(job) = ch
        .store
        .claim_job(&lease(), stepsim_server::now_s())
        .await
        .unwrap()
    {
        let r = stepsim_server::score_entry(&ch, &job);
        ch.store
            .finish_job(job.id, "test", r, stepsim_server::SCORER_VERSION, 0)
            .await
            .unwrap();
    }
}
