//! `stepsim slurm`: print a submit script that runs a whole challenge on a
//! Slurm cluster (docs/cluster.md): a job array of `generate` shards, a
//! finishing job, a job array of `measure` shards, its finishing job, and a
//! `score` job, each depending on the one before (`--dependency=afterok`).

use std::path::{Path, PathBuf};

/// Arguments of `stepsim slurm`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The JSON config of the run (its absolute path goes into the script).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// The run directory, on a file system every node shares.
    #[arg(long, value_name = "RUN")]
    out: PathBuf,
    /// Number of shards of generate and of measure (the array size).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=100_000))]
    shards: u32,
    /// Slurm partition (sbatch --partition); the cluster's default if absent.
    #[arg(long, value_name = "P")]
    partition: Option<String>,
    /// Time limit of each job (sbatch --time), e.g. 2:00:00.
    #[arg(long, value_name = "T")]
    time: Option<String>,
    /// Cores of each job (sbatch --cpus-per-task; also stepsim --threads).
    #[arg(long, value_name = "C", value_parser = clap::value_parser!(u32).range(1..=1024))]
    cpus_per_task: Option<u32>,
    /// Memory of each job (sbatch --mem), e.g. 8G.
    #[arg(long, value_name = "M")]
    mem: Option<String>,
    /// Slurm account to charge (sbatch --account).
    #[arg(long, value_name = "A")]
    account: Option<String>,
    /// The submission `measure` writes (default: RUN-ksb.txt beside RUN).
    #[arg(long, value_name = "FILE")]
    submission: Option<PathBuf>,
    /// The directory `score` writes its report to (default: RUN-report).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Where the jobs' logs go (default: RUN-logs).
    #[arg(long, value_name = "DIR")]
    logs: Option<PathBuf>,
    /// The stepsim binary the jobs run (default: this one).
    #[arg(long, value_name = "PATH")]
    stepsim: Option<PathBuf>,
}

/// Prints the script.
pub fn run(args: &Args) -> anyhow::Result<()> {
    use anyhow::Context as _;
    // The config must exist and be valid now, not when the first job starts.
    stepsim_sim::Plan::load(&args.config, &[])?;
    let cwd = std::env::current_dir().context("cannot read the current directory")?;
    let stepsim = match &args.stepsim {
        Some(p) => absolute(&cwd, p),
        None => std::env::current_exe().context("cannot find the stepsim binary")?,
    };
    let plan = Script {
        stepsim,
        config: absolute(&cwd, &args.config),
        run: absolute(&cwd, &args.out),
        submission: args.submission.as_ref().map(|p| absolute(&cwd, p)),
        report: args.report.as_ref().map(|p| absolute(&cwd, p)),
        logs: args.logs.as_ref().map(|p| absolute(&cwd, p)),
        shards: args.shards,
        partition: args.partition.clone(),
        time: args.time.clone(),
        cpus_per_task: args.cpus_per_task,
        mem: args.mem.clone(),
        account: args.account.clone(),
    };
    print!("{}", plan.text());
    Ok(())
}

fn absolute(cwd: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.into()
    } else {
        cwd.join(p)
    }
}

/// What the script runs, with absolute paths.
#[derive(Debug, Clone)]
pub struct Script {
    /// The stepsim binary.
    pub stepsim: PathBuf,
    /// The config.
    pub config: PathBuf,
    /// The run directory.
    pub run: PathBuf,
    /// The submission (default `RUN-ksb.txt`).
    pub submission: Option<PathBuf>,
    /// The report directory (default `RUN-report`).
    pub report: Option<PathBuf>,
    /// The log directory (default `RUN-logs`).
    pub logs: Option<PathBuf>,
    /// Shards of generate and measure.
    pub shards: u32,
    /// sbatch --partition.
    pub partition: Option<String>,
    /// sbatch --time.
    pub time: Option<String>,
    /// sbatch --cpus-per-task and stepsim --threads.
    pub cpus_per_task: Option<u32>,
    /// sbatch --mem.
    pub mem: Option<String>,
    /// sbatch --account.
    pub account: Option<String>,
}

/// Quotes `s` for a POSIX shell: unchanged when made of safe characters,
/// otherwise in single quotes (a `'` becomes `'\''`).
pub fn shell_quote(s: &str) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || "_-./:=+,@%".contains(c);
    if !s.is_empty() && s.chars().all(safe) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

fn sibling(run: &Path, suffix: &str) -> PathBuf {
    let mut name = run
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_else(|| "run".into());
    name.push(suffix);
    run.with_file_name(name)
}

impl Script {
    /// The submit script.
    pub fn text(&self) -> String {
        let q = |p: &Path| shell_quote(&p.to_string_lossy());
        let submission = self
            .submission
            .clone()
            .unwrap_or_else(|| sibling(&self.run, "-ksb.txt"));
        let report = self
            .report
            .clone()
            .unwrap_or_else(|| sibling(&self.run, "-report"));
        let logs = self
            .logs
            .clone()
            .unwrap_or_else(|| sibling(&self.run, "-logs"));
        let threads = self
            .cpus_per_task
            .map(|c| format!(" --threads {c}"))
            .unwrap_or_default();
        let n = self.shards;
        let mut resources = Vec::new();
        if let Some(p) = &self.partition {
            resources.push(format!("--partition={}", shell_quote(p)));
        }
        if let Some(a) = &self.account {
            resources.push(format!("--account={}", shell_quote(a)));
        }
        if let Some(t) = &self.time {
            resources.push(format!("--time={}", shell_quote(t)));
        }
        if let Some(c) = self.cpus_per_task {
            resources.push(format!("--cpus-per-task={c}"));
        }
        if let Some(m) = &self.mem {
            resources.push(format!("--mem={}", shell_quote(m)));
        }
        let run_dir = stepsim_contract::run_dir::RunDir::new(&self.run);
        let (public, private) = (run_dir.public().path(), run_dir.private().path());
        let (stepsim, config, run) = (q(&self.stepsim), q(&self.config), q(&self.run));
        let gen_shard =
            format!("{stepsim} generate --config {config} --out {run} --shard auto{threads}");
        let gen_finish =
            format!("{stepsim} generate --config {config} --out {run} --finish{threads}");
        let measure = |tail: &str| {
            format!(
                "{stepsim} measure --run {} --out {} {tail}{threads}",
                q(public),
                q(&submission)
            )
        };
        let score = format!(
            "{stepsim} score --truth {} --submission {} --out {} --force",
            q(private),
            q(&submission),
            q(&report)
        );
        let mut s = String::new();
        s.push_str("#!/bin/bash\n");
        s.push_str(&format!(
            "# Made by `stepsim slurm`: the whole challenge of {} on Slurm,\n",
            self.config.display()
        ));
        s.push_str(&format!(
            "# in {n} shards. Run it on a login node: bash THIS_FILE. It submits five\n"
        ));
        s.push_str("# jobs, each starting only when the one before succeeded (afterok):\n");
        s.push_str("#   generate shards (array) -> generate --finish -> measure shards (array)\n");
        s.push_str("#   -> measure --finish -> score.\n");
        s.push_str("# A failed or cancelled shard K is rerun alone (its own job, not an array):\n");
        s.push_str(&format!(
            "#   sbatch --wrap={}\n",
            shell_quote(&format!(
                "{stepsim} generate --config {config} --out {run} --shard K/{n}{threads}"
            ))
        ));
        s.push_str("# then submit the finishing job again (the dependent jobs of a failed array never start).\n");
        s.push_str("set -euo pipefail\n\n");
        s.push_str(&format!("mkdir -p {}\n", q(&logs)));
        s.push_str(&format!("common=({})\n", resources.join(" ")));
        s.push_str("submit() {\n  local id\n  id=$(sbatch --parsable \"${common[@]}\" \"$@\")\n  echo \"${id%%;*}\"\n}\n\n");
        let log = |name: &str| q(&logs.join(name));
        let job =
            |var: &str, name: &str, dep: Option<&str>, array: bool, log_name: &str, cmd: &str| {
                let mut line = format!("{var}=$(submit --job-name={name}");
                if array {
                    line.push_str(&format!(" --array=1-{n}"));
                }
                if let Some(d) = dep {
                    line.push_str(&format!(" --dependency=afterok:\"${d}\""));
                }
                line.push_str(&format!(
                    " --output={} --wrap={})\n",
                    log(log_name),
                    shell_quote(cmd)
                ));
                line
            };
        s.push_str(&job(
            "gen",
            "stepsim-generate",
            None,
            true,
            "generate-%A_%a.out",
            &gen_shard,
        ));
        s.push_str(&job(
            "gen_finish",
            "stepsim-generate-finish",
            Some("gen"),
            false,
            "generate-finish-%j.out",
            &gen_finish,
        ));
        s.push_str(&job(
            "meas",
            "stepsim-measure",
            Some("gen_finish"),
            true,
            "measure-%A_%a.out",
            &measure("--shard auto"),
        ));
        s.push_str(&job(
            "meas_finish",
            "stepsim-measure-finish",
            Some("meas"),
            false,
            "measure-finish-%j.out",
            &measure("--finish"),
        ));
        s.push_str(&job(
            "score",
            "stepsim-score",
            Some("meas_finish"),
            false,
            "score-%j.out",
            &score,
        ));
        s.push_str(&format!(
            "\necho \"submitted: generate $gen, generate-finish $gen_finish, measure $meas, measure-finish $meas_finish, score $score\"\necho \"logs in {}; follow with: squeue --me\"\n",
            logs.display()
        ));
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn script() -> Script {
        Script {
            stepsim: "/opt/stepsim/bin/stepsim".into(),
            config: "/shared/step1.json".into(),
            run: "/shared/runs/step1".into(),
            submission: None,
            report: None,
            logs: None,
            shards: 16,
            partition: Some("compute".into()),
            time: Some("2:00:00".into()),
            cpus_per_task: Some(8),
            mem: Some("16G".into()),
            account: None,
        }
    }

    #[test]
    fn the_script_chains_arrays_and_finishing_jobs_with_afterok() {
        let t = script().text();
        let lines: Vec<&str> = t.lines().filter(|l| l.contains("=$(submit")).collect();
        assert_eq!(lines.len(), 5, "{t}");
        assert_eq!(
            lines[0],
            "gen=$(submit --job-name=stepsim-generate --array=1-16 --output=/shared/runs/step1-logs/generate-%A_%a.out --wrap='/opt/stepsim/bin/stepsim generate --config /shared/step1.json --out /shared/runs/step1 --shard auto --threads 8')"
        );
        assert_eq!(
            lines[1],
            "gen_finish=$(submit --job-name=stepsim-generate-finish --dependency=afterok:\"$gen\" --output=/shared/runs/step1-logs/generate-finish-%j.out --wrap='/opt/stepsim/bin/stepsim generate --config /shared/step1.json --out /shared/runs/step1 --finish --threads 8')"
        );
        assert!(lines[2].starts_with("meas=$(submit --job-name=stepsim-measure --array=1-16 --dependency=afterok:\"$gen_finish\""), "{}", lines[2]);
        assert!(lines[2].contains("measure --run /shared/runs/step1/public --out /shared/runs/step1-ksb.txt --shard auto --threads 8"), "{}", lines[2]);
        assert!(
            lines[3].contains("--dependency=afterok:\"$meas\"")
                && lines[3].contains("--out /shared/runs/step1-ksb.txt --finish"),
            "{}",
            lines[3]
        );
        assert!(
            lines[4].contains("--dependency=afterok:\"$meas_finish\""),
            "{}",
            lines[4]
        );
        assert!(lines[4].contains("score --truth /shared/runs/step1/private --submission /shared/runs/step1-ksb.txt --out /shared/runs/step1-report"), "{}", lines[4]);
        assert!(
            t.contains("common=(--partition=compute --time=2:00:00 --cpus-per-task=8 --mem=16G)"),
            "{t}"
        );
        assert!(t.starts_with("#!/bin/bash\n") && t.contains("set -euo pipefail"));
        assert!(t.contains("--shard K/16"), "{t}");
    }

    #[test]
    fn paths_with_spaces_and_quotes_are_quoted_twice() {
        assert_eq!(shell_quote("/a/b-c_1.json"), "/a/b-c_1.json");
        assert_eq!(shell_quote("a b"), "'a b'");
        assert_eq!(shell_quote("it's"), r"'it'\''s'");
        assert_eq!(shell_quote(""), "''");
        let mut s = script();
        s.run = "/shared/my run's".into();
        s.partition = None;
        s.time = None;
        s.cpus_per_task = None;
        s.mem = None;
        let t = s.text();
        assert!(t.contains("common=()"), "{t}");
        // The --wrap argument is quoted for the submit script, and inside it
        // the path is quoted for the job's shell.
        let line = t.lines().find(|l| l.starts_with("gen=")).unwrap();
        let inner = shell_quote("/shared/my run's");
        let wrap = shell_quote(&format!(
            "/opt/stepsim/bin/stepsim generate --config /shared/step1.json --out {inner} --shard auto"
        ));
        assert!(line.ends_with(&format!("--wrap={wrap})")), "{line}");
    }
}
