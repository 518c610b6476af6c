//! The paths of a run directory (SPEC §5, `docs/run-layout.md`): the one
//! place that spells them.
//!
//! ```text
//! RUN/                          RunDir
//!   public/                     PublicDir: what participants get
//!     manifest.json             PublicDir::manifest
//!     README.md                 PublicDir::readme
//!     <dataset-id>/             PublicDir::dataset
//!       <image-id>.fits         PublicDir::image (PublicDir::image_file relative to public/)
//!   private/                    PrivateDir: what the organiser keeps
//!     config.json               PrivateDir::config
//!     datasets.json             PrivateDir::datasets
//!     blinding.key              PrivateDir::blinding_key
//!     inputs/                   PrivateDir::inputs (copies of the config's input files)
//!     truth/<image-id>.fits     PrivateDir::truth_dir, PrivateDir::truth
//!     model/<image-id>.fits     PrivateDir::model_dir, PrivateDir::model
//!     done/<image-id>.json      PrivateDir::done_dir, PrivateDir::sidecar
//!     shards/K-of-N.json        PrivateDir::shards_dir, PrivateDir::shard_marker
//!     psf/<psf-name>.fits       PrivateDir::psf_dir, PrivateDir::psf
//!     psf/cache/                PrivateDir::psf_cache
//! ```
//!
//! A run's two halves travel on their own: participants get `public/` and
//! may keep it under any name (`stepsim measure --run`), and the scorer is
//! given the private half (`stepsim score --truth`). So [`PublicDir`] and
//! [`PrivateDir`] are made from the half's own directory, and [`RunDir`]
//! from the run's root holds one of each. No other code joins the names of
//! a run's files (`tests/architecture.rs` checks it).

use std::path::{Path, PathBuf};

/// A run directory `RUN` (SPEC §5): its public and private halves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunDir {
    root: PathBuf,
    public: PublicDir,
    private: PrivateDir,
}

impl RunDir {
    /// The run whose root is `root` (`--out RUN` of `stepsim generate`).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        let root = root.into();
        RunDir {
            public: PublicDir::new(root.join("public")),
            private: PrivateDir::new(root.join("private")),
            root,
        }
    }

    /// `RUN`.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `RUN/public/`: what participants get; nothing in it reveals truth.
    pub fn public(&self) -> &PublicDir {
        &self.public
    }

    /// `RUN/private/`: what the organiser keeps.
    pub fn private(&self) -> &PrivateDir {
        &self.private
    }
}

/// The public half of a run, `RUN/public/` (SPEC §5), wherever it is kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PublicDir {
    dir: PathBuf,
}

impl PublicDir {
    /// Name of the manifest in the public half, relative to it (as the
    /// server's data listing and archive name it).
    pub const MANIFEST: &'static str = "manifest.json";
    /// Name of the participants' README in the public half, relative to it.
    pub const README: &'static str = "README.md";

    /// The public half kept in `dir` (`RUN/public`, or a participant's copy).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        PublicDir { dir: dir.into() }
    }

    /// The directory itself.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// `public/manifest.json` ([`crate::run_layout::Manifest`]).
    pub fn manifest(&self) -> PathBuf {
        self.dir.join(Self::MANIFEST)
    }

    /// `public/README.md`, for participants: the data and the submission
    /// format.
    pub fn readme(&self) -> PathBuf {
        self.dir.join(Self::README)
    }

    /// `public/<dataset-id>/`, the images of a dataset.
    pub fn dataset(&self, dataset: &str) -> PathBuf {
        self.dir.join(dataset)
    }

    /// `<dataset-id>/<image-id>.fits`: an image's path relative to
    /// `public/`, as the manifest's `file` names it.
    pub fn image_file(dataset: &str, image: &str) -> String {
        format!("{dataset}/{image}.fits")
    }

    /// `public/<dataset-id>/<image-id>.fits`, a public image.
    pub fn image(&self, dataset: &str, image: &str) -> PathBuf {
        self.file(&Self::image_file(dataset, image))
    }

    /// `public/<file>`: a file named relative to `public/` (a manifest's
    /// `file`, [`Self::MANIFEST`], [`Self::README`]).
    pub fn file(&self, file: &str) -> PathBuf {
        self.dir.join(file)
    }
}

/// The private half of a run, `RUN/private/` (SPEC §5), wherever it is
/// kept: the answers and everything needed to remake the run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PrivateDir {
    dir: PathBuf,
}

impl PrivateDir {
    /// The directory of the input copies, relative to `private/`.
    const INPUTS: &'static str = "inputs";

    /// Name of the datasets file in the private half, relative to it.
    pub const DATASETS: &'static str = "datasets.json";

    /// The private half kept in `dir` (`RUN/private`, or the organiser's
    /// copy given to `stepsim score --truth`).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        PrivateDir { dir: dir.into() }
    }

    /// The directory itself.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// `private/config.json`: the resolved config, including the seed; the
    /// first file a run writes, and never replaced (it claims the run).
    pub fn config(&self) -> PathBuf {
        self.dir.join("config.json")
    }

    /// `private/datasets.json` ([`crate::run_layout::Datasets`]): dataset id ->
    /// PSF, shear, images and base fields.
    pub fn datasets(&self) -> PathBuf {
        self.dir.join(Self::DATASETS)
    }

    /// `private/blinding.key`: the secret from which the opaque ids derive.
    pub fn blinding_key(&self) -> PathBuf {
        self.dir.join("blinding.key")
    }

    /// `private/inputs/`: the run's copies of the input files its config
    /// names.
    pub fn inputs(&self) -> PathBuf {
        self.dir.join(Self::INPUTS)
    }

    /// `inputs/list_{field}.list`: where the copies of a run's SkyMaker
    /// lists go, relative to `private/` (as `private/config.json` names
    /// them), `{field}` standing for the base field.
    pub fn skymaker_list_copy_pattern() -> String {
        format!("{}/list_{{field}}.list", Self::INPUTS)
    }

    /// `inputs/psf_<index>.fits`: the copy of the image of `fits` PSF
    /// `index` (config order), relative to `private/`.
    pub fn fits_psf_copy(index: usize) -> String {
        format!("{}/psf_{index}.fits", Self::INPUTS)
    }

    /// `private/<name>`: the copy of an input named relative to `private/`
    /// ([`Self::skymaker_list_copy_pattern`], [`Self::fits_psf_copy`]).
    pub fn input(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// `private/truth/`, the truth tables.
    pub fn truth_dir(&self) -> PathBuf {
        self.dir.join("truth")
    }

    /// `private/truth/<image-id>.fits`, the truth table of an image (SPEC §5
    /// columns).
    pub fn truth(&self, image: &str) -> PathBuf {
        self.truth_dir().join(format!("{image}.fits"))
    }

    /// `private/model/`, the noise-free models (`output.write_model`).
    pub fn model_dir(&self) -> PathBuf {
        self.dir.join("model")
    }

    /// `private/model/<image-id>.fits`, the noise-free, sky-free model of an
    /// image.
    pub fn model(&self, image: &str) -> PathBuf {
        self.model_dir().join(format!("{image}.fits"))
    }

    /// `private/done/`, the sidecars.
    pub fn done_dir(&self) -> PathBuf {
        self.dir.join("done")
    }

    /// `private/done/<image-id>.json`, the sidecar that marks an image
    /// finished.
    pub fn sidecar(&self, image: &str) -> PathBuf {
        self.done_dir().join(format!("{image}.json"))
    }

    /// `private/shards/`, the done-markers of shards.
    pub fn shards_dir(&self) -> PathBuf {
        self.dir.join("shards")
    }

    /// `K-of-N.json`, the file name of the done-marker of shard `k` of `n`.
    pub fn shard_marker_name(k: u32, n: u32) -> String {
        format!("{k}-of-{n}.json")
    }

    /// `private/shards/K-of-N.json`, the done-marker of shard `k` of `n`.
    pub fn shard_marker(&self, k: u32, n: u32) -> PathBuf {
        self.shards_dir().join(Self::shard_marker_name(k, n))
    }

    /// `private/psf/`, the PSF files of the run (`output.write_psf`).
    pub fn psf_dir(&self) -> PathBuf {
        self.dir.join("psf")
    }

    /// `private/psf/<psf-name>.fits`, the PSF at image sampling and
    /// oversampled.
    pub fn psf(&self, name: &str) -> PathBuf {
        self.psf_dir().join(format!("{name}.fits"))
    }

    /// `private/psf/cache/`, the run's PSF store: solved PSFs reused by every
    /// later process of the run.
    pub fn psf_cache(&self) -> PathBuf {
        self.psf_dir().join("cache")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout of SPEC §5 and docs/run-layout.md, spelled from outside.
    #[test]
    fn every_path_is_the_documented_one() {
        let run = RunDir::new("RUN");
        let (public, private) = (run.public(), run.private());
        let p = |p: PathBuf| p.to_str().unwrap().to_owned();
        assert_eq!(run.root(), Path::new("RUN"));
        assert_eq!(public.path(), Path::new("RUN/public"));
        assert_eq!(private.path(), Path::new("RUN/private"));
        let cases = [
            (public.manifest(), "RUN/public/manifest.json"),
            (public.readme(), "RUN/public/README.md"),
            (public.dataset("d1"), "RUN/public/d1"),
            (public.image("d1", "i2"), "RUN/public/d1/i2.fits"),
            (public.file("d1/i2.fits"), "RUN/public/d1/i2.fits"),
            (private.config(), "RUN/private/config.json"),
            (private.datasets(), "RUN/private/datasets.json"),
            (private.blinding_key(), "RUN/private/blinding.key"),
            (private.inputs(), "RUN/private/inputs"),
            (
                private.input(&PrivateDir::fits_psf_copy(3)),
                "RUN/private/inputs/psf_3.fits",
            ),
            (private.truth_dir(), "RUN/private/truth"),
            (private.truth("i2"), "RUN/private/truth/i2.fits"),
            (private.model_dir(), "RUN/private/model"),
            (private.model("i2"), "RUN/private/model/i2.fits"),
            (private.done_dir(), "RUN/private/done"),
            (private.sidecar("i2"), "RUN/private/done/i2.json"),
            (private.shards_dir(), "RUN/private/shards"),
            (private.shard_marker(2, 7), "RUN/private/shards/2-of-7.json"),
            (private.psf_dir(), "RUN/private/psf"),
            (private.psf("coma"), "RUN/private/psf/coma.fits"),
            (private.psf_cache(), "RUN/private/psf/cache"),
        ];
        for (got, want) in cases {
            assert_eq!(p(got), want);
        }
        assert_eq!(PublicDir::image_file("d1", "i2"), "d1/i2.fits");
        assert_eq!(
            PrivateDir::skymaker_list_copy_pattern(),
            "inputs/list_{field}.list"
        );
        // A half kept on its own has the same inside.
        assert_eq!(
            PrivateDir::new("truth-copy").truth("i2"),
            Path::new("truth-copy/truth/i2.fits")
        );
        assert_eq!(
            PublicDir::new("data").manifest(),
            Path::new("data/manifest.json")
        );
    }
}
