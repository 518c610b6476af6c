//! `stepsim leaderboard`: rank several score reports in one table.

use std::path::PathBuf;
use stepsim_harness::{check_comparable, leaderboard_markdown, rank, read_report};

/// Arguments of `stepsim leaderboard`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// report.json files written by `stepsim score`.
    #[arg(required = true, value_name = "REPORT.json")]
    reports: Vec<PathBuf>,
    /// Write leaderboard.md, leaderboard.json and the ⟨m⟩–σ_c plot here
    /// (default: print the Markdown table).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Overwrite the files of an earlier leaderboard in --out.
    #[arg(long)]
    force: bool,
}

/// The files `leaderboard --out DIR` writes, in the order written.
const OUTPUTS: [&str; 4] = [
    "fig3_m_sigma_c.svg",
    "fig3_m_sigma_c.png",
    "leaderboard.md",
    "leaderboard.json",
];

/// Ranks the reports (by Q_c, larger first).
pub fn run(args: &Args) -> anyhow::Result<()> {
    if let (Some(dir), false) = (&args.out, args.force) {
        if let Some(path) = OUTPUTS
            .iter()
            .map(|n| dir.join(n))
            .find(|p| std::fs::symlink_metadata(p).is_ok())
        {
            return Err(stepsim_harness::HarnessError::ReportExists { path }.into());
        }
    }
    let reports = args
        .reports
        .iter()
        .map(|p| Ok((p.clone(), read_report(p)?)))
        .collect::<Result<Vec<_>, stepsim_harness::HarnessError>>()?;
    check_comparable(&reports)?;
    let board = rank(&reports);
    let md = leaderboard_markdown(&reports, &board);
    match &args.out {
        None => print!("{md}"),
        Some(dir) => {
            let mut json = serde_json::to_string_pretty(&board)?;
            json.push('\n');
            let refs: Vec<&stepsim_harness::Report> = reports.iter().map(|r| &r.1).collect();
            let fig = stepsim_harness::fig3(&refs);
            let bytes = [
                fig.to_svg().into_bytes(),
                fig.to_png()?,
                md.into_bytes(),
                json.into_bytes(),
            ];
            for (name, b) in OUTPUTS.iter().zip(&bytes) {
                stepsim_contract::io::write_bytes_atomically(&dir.join(name), b)?;
            }
            eprintln!(
                "stepsim: leaderboard of {} reports in {}",
                reports.len(),
                dir.display()
            );
        }
    }
    Ok(())
}
