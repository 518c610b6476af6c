//! What `generate` tells its user while it works: a bar on a terminal, log
//! lines elsewhere (one per PSF built, and one every tenth of the images or
//! every [`LOG_EVERY_S`] seconds, whichever comes first).

use std::sync::Mutex;
use std::time::{Duration, Instant};
use stepsim_sim::io::psf_store::Origin;
use stepsim_sim::run::generate::Event;

/// Longest silence between two log lines while images are made.
pub const LOG_EVERY_S: u64 = 30;

/// The log line after `done` of `total` images, `elapsed` after the first
/// image was started (the rate of the images so far gives the time left).
pub fn images_line(done: usize, total: usize, elapsed: Duration) -> String {
    count_line("images written", done, total, elapsed)
}

/// "stepsim: done/total what (pct%), s s, about left s left": a progress
/// line of `generate` or `measure`, the time left from the rate so far.
pub fn count_line(what: &str, done: usize, total: usize, elapsed: Duration) -> String {
    let s = elapsed.as_secs_f64();
    let left = if done > 0 && done < total {
        format!(
            ", about {:.0} s left",
            s / done as f64 * (total - done) as f64
        )
    } else {
        String::new()
    };
    format!(
        "stepsim: {done}/{total} {what} ({:.0}%), {s:.0} s{left}",
        100.0 * done as f64 / total.max(1) as f64
    )
}

/// "building N PSFs" (singular for one).
pub fn psfs_message(total: usize) -> String {
    format!("building {total} PSF{}", if total == 1 { "" } else { "s" })
}

/// The bar's template once `done` images are written: no time left is
/// shown before the first image is finished (indicatif's estimate would
/// read "eta 0s" from no rate at all).
pub fn bar_template(done: u64) -> &'static str {
    if done == 0 {
        "{spinner} {pos}/{len} images [{elapsed_precise}, estimating time left] {wide_bar}"
    } else {
        "{spinner} {pos}/{len} images [{elapsed_precise}, eta {eta}] {wide_bar}"
    }
}

fn bar_style(done: u64) -> indicatif::ProgressStyle {
    indicatif::ProgressStyle::with_template(bar_template(done)).expect("valid template")
}

/// Tells the user about events, on a bar or in log lines.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    state: Mutex<State>,
}

struct State {
    started: Instant,
    images_started: Instant,
    last_line: Instant,
    pending: usize,
    written: usize,
}

impl Progress {
    /// A bar when stderr is a terminal (and `CI` is unset), log lines
    /// otherwise.
    pub fn new() -> Self {
        use std::io::IsTerminal as _;
        let bar =
            (std::io::stderr().is_terminal() && std::env::var_os("CI").is_none()).then(|| {
                let b = indicatif::ProgressBar::new_spinner();
                b.enable_steady_tick(Duration::from_millis(200));
                b.set_message("preparing");
                b
            });
        let now = Instant::now();
        Self {
            bar,
            state: Mutex::new(State {
                started: now,
                images_started: now,
                last_line: now,
                pending: 0,
                written: 0,
            }),
        }
    }

    /// Handles one event.
    pub fn event(&self, e: Event) {
        let mut st = self.state.lock().unwrap_or_else(|p| p.into_inner());
        match (e, &self.bar) {
            (Event::PsfsStart { total }, Some(bar)) if total > 0 => {
                bar.set_message(psfs_message(total));
            }
            (Event::PsfsStart { total }, None) if total > 0 => {
                eprintln!("stepsim: {}", psfs_message(total));
            }
            (Event::PsfsStart { .. }, _) => {}
            (
                Event::PsfBuilt {
                    name,
                    done,
                    total,
                    origin,
                },
                bar,
            ) => {
                let line = psf_line(&name, done, total, &origin);
                match bar {
                    // A rebuilt file is worth a line that stays.
                    Some(bar) if matches!(origin, Origin::Rebuilt { .. }) => {
                        bar.println(format!("stepsim: {line}"));
                    }
                    Some(bar) => bar.set_message(line),
                    None => eprintln!(
                        "stepsim: {line}, {:.0} s",
                        st.started.elapsed().as_secs_f64()
                    ),
                }
            }
            (Event::Start { pending, .. }, bar) => {
                st.pending = pending;
                st.images_started = Instant::now();
                st.last_line = st.images_started;
                if let Some(bar) = bar {
                    bar.set_style(bar_style(0));
                    bar.set_length(pending as u64);
                    // The time spent on PSFs is not the images' rate.
                    bar.reset();
                } else if pending > 0 {
                    eprintln!("stepsim: making {}", images(pending));
                }
            }
            (Event::ImageWritten, Some(bar)) => {
                st.written += 1;
                if st.written == 1 {
                    bar.set_style(bar_style(1));
                }
                bar.inc(1);
            }
            (Event::ImageWritten, None) => {
                st.written += 1;
                let step = st.pending.div_ceil(10).max(1);
                let quiet = st.last_line.elapsed() >= Duration::from_secs(LOG_EVERY_S);
                if st.written % step == 0 || st.written == st.pending || quiet {
                    st.last_line = Instant::now();
                    eprintln!(
                        "{}",
                        images_line(st.written, st.pending, st.images_started.elapsed())
                    );
                }
            }
        }
    }

    /// Removes the bar.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// `n` images, in the singular for one ("1 image", "0 images", "8 images").
pub fn images(n: usize) -> String {
    format!("{n} image{}", if n == 1 { "" } else { "s" })
}

/// The progress line of one PSF: built, stored, reused or rebuilt.
fn psf_line(name: &str, done: usize, total: usize, origin: &Origin) -> String {
    match origin {
        Origin::Built => format!("built PSF {done}/{total} ({name})"),
        Origin::Stored { file } => {
            format!(
                "built PSF {done}/{total} ({name}), stored in {}",
                file.display()
            )
        }
        Origin::Reused { file } => {
            format!("reused PSF {done}/{total} ({name}) from {}", file.display())
        }
        Origin::Copied { file, from } => format!(
            "reused PSF {done}/{total} ({name}) from the user's store {}, copied to {}",
            from.display(),
            file.display()
        ),
        Origin::Rebuilt { file, why } => format!(
            "rebuilt PSF {done}/{total} ({name}): {} {why}; stored again",
            file.display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_image_is_said_in_the_singular() {
        assert_eq!(images(1), "1 image");
        assert_eq!(images(0), "0 images");
        assert_eq!(images(8), "8 images");
    }

    #[test]
    fn the_bar_shows_no_time_left_before_the_first_image_and_one_psf_is_singular() {
        assert!(!bar_template(0).contains("{eta}"));
        assert!(bar_template(0).contains("estimating time left"));
        assert!(bar_template(1).contains("eta {eta}"));
        assert_eq!(psfs_message(1), "building 1 PSF");
        assert_eq!(psfs_message(6), "building 6 PSFs");
    }

    #[test]
    fn measure_lines_say_how_far_and_how_long() {
        assert_eq!(
            count_line("images measured", 64, 320, Duration::from_secs(240)),
            "stepsim: 64/320 images measured (20%), 240 s, about 960 s left"
        );
    }

    #[test]
    fn image_lines_give_share_elapsed_and_time_left_from_the_rate() {
        assert_eq!(
            images_line(3, 12, Duration::from_secs(6)),
            "stepsim: 3/12 images written (25%), 6 s, about 18 s left"
        );
        assert_eq!(
            images_line(12, 12, Duration::from_secs(20)),
            "stepsim: 12/12 images written (100%), 20 s"
        );
        assert_eq!(
            images_line(0, 0, Duration::ZERO),
            "stepsim: 0/0 images written (0%), 0 s"
        );
    }
}
