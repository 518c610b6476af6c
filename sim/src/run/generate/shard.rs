//! `--shard K/N`: which images one process makes.
//!
//! The images of a run are listed in a canonical order (base field, then
//! rotated twin, then dataset); image `j` (0-based) of that list belongs to
//! shard `j mod N + 1`. The assignment depends only on the plan, so N
//! processes with K = 1..N make every image exactly once, in any order, on
//! any machines sharing the run directory.

use std::fmt;
use std::str::FromStr;

/// One share of a run: shard `k` of `n` (1-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// This shard, 1..=n.
    pub k: u32,
    /// Number of shards, ≥ 1.
    pub n: u32,
}

impl Shard {
    /// The whole run.
    pub const ALL: Shard = Shard { k: 1, n: 1 };

    /// True when image `j` of the canonical order belongs to this shard.
    pub fn owns(&self, j: usize) -> bool {
        j % self.n as usize == (self.k - 1) as usize
    }
}

impl Default for Shard {
    fn default() -> Self {
        Self::ALL
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

/// A malformed `--shard` value.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("shard must be K/N with 1 ≤ K ≤ N, got {0:?}")]
pub struct BadShard(pub String);

impl FromStr for Shard {
    type Err = BadShard;
    fn from_str(s: &str) -> Result<Self, BadShard> {
        let bad = || BadShard(s.into());
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let k: u32 = k.trim().parse().map_err(|_| bad())?;
        let n: u32 = n.trim().parse().map_err(|_| bad())?;
        if k == 0 || n == 0 || k > n {
            return Err(bad());
        }
        Ok(Self { k, n })
    }
}

/// Slurm's job-array variables that `--shard auto` reads: the task's id,
/// the number of tasks and the lowest id of the array.
pub const SLURM_ARRAY_VARS: [&str; 3] = [
    "SLURM_ARRAY_TASK_ID",
    "SLURM_ARRAY_TASK_COUNT",
    "SLURM_ARRAY_TASK_MIN",
];

/// Why `--shard auto` cannot take its shard from Slurm's variables.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AutoShardError {
    /// A variable is not set: not inside a Slurm job array.
    #[error(
        "{0} is not set: --shard auto takes K and N from a Slurm job array (sbatch --array=1-N); outside one give --shard K/N"
    )]
    Missing(&'static str),
    /// A variable is not a whole number.
    #[error(
        "{var}={value:?} is not a whole number (--shard auto reads Slurm's job-array variables)"
    )]
    NotANumber {
        /// The variable.
        var: &'static str,
        /// Its value.
        value: String,
    },
    /// The variables do not describe one task of a contiguous array.
    #[error(
        "SLURM_ARRAY_TASK_ID={id}, SLURM_ARRAY_TASK_COUNT={count}, SLURM_ARRAY_TASK_MIN={min} do not give a shard K = ID - MIN + 1 with 1 <= K <= COUNT; --shard auto needs a contiguous array without a step (sbatch --array=1-N)"
    )]
    Inconsistent {
        /// SLURM_ARRAY_TASK_ID.
        id: u64,
        /// SLURM_ARRAY_TASK_COUNT.
        count: u64,
        /// SLURM_ARRAY_TASK_MIN.
        min: u64,
    },
}

impl Shard {
    /// The shard of a Slurm array task, from `var` (the environment, or a
    /// table in tests): K = `SLURM_ARRAY_TASK_ID` − `SLURM_ARRAY_TASK_MIN` + 1
    /// and N = `SLURM_ARRAY_TASK_COUNT`. Refused when a variable is
    /// missing or not a number, or when 1 ≤ K ≤ N fails (an array with a
    /// step such as `--array=1-7:2`, or made of separate ranges).
    pub fn from_slurm(var: impl Fn(&str) -> Option<String>) -> Result<Shard, AutoShardError> {
        let mut v = [0u64; 3];
        for (slot, name) in v.iter_mut().zip(SLURM_ARRAY_VARS) {
            let value = var(name).ok_or(AutoShardError::Missing(name))?;
            *slot = value
                .trim()
                .parse()
                .map_err(|_| AutoShardError::NotANumber { var: name, value })?;
        }
        let [id, count, min] = v;
        let bad = AutoShardError::Inconsistent { id, count, min };
        if id < min || count == 0 || count > u64::from(u32::MAX) {
            return Err(bad);
        }
        let k = id - min + 1;
        if k > count {
            return Err(bad);
        }
        Ok(Shard {
            k: k as u32,
            n: count as u32,
        })
    }

    /// The file name of this shard's done-marker, `K-of-N.json`.
    pub fn marker_name(&self) -> String {
        stepsim_contract::run_dir::PrivateDir::shard_marker_name(self.k, self.n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(pairs: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |name| {
            pairs
                .iter()
                .find(|(k, _)| *k == name)
                .map(|(_, v)| v.to_string())
        }
    }

    #[test]
    fn auto_takes_the_shard_from_slurm_array_variables() {
        let ok = |id, count, min| {
            Shard::from_slurm(env(&[
                ("SLURM_ARRAY_TASK_ID", id),
                ("SLURM_ARRAY_TASK_COUNT", count),
                ("SLURM_ARRAY_TASK_MIN", min),
            ]))
        };
        assert_eq!(ok("1", "4", "1"), Ok(Shard { k: 1, n: 4 }));
        assert_eq!(ok("4", "4", "1"), Ok(Shard { k: 4, n: 4 }));
        // Arrays that start at 0 or elsewhere: K counts from MIN.
        assert_eq!(ok("0", "3", "0"), Ok(Shard { k: 1, n: 3 }));
        assert_eq!(ok("12", "3", "10"), Ok(Shard { k: 3, n: 3 }));
        assert_eq!(ok(" 2 ", "2", "1"), Ok(Shard { k: 2, n: 2 }));
        // A step (--array=1-7:2 has COUNT 4: task 7 gives K 7) or an id
        // below the minimum: refused, naming the values.
        let e = ok("7", "4", "1").unwrap_err();
        assert_eq!(
            e,
            AutoShardError::Inconsistent {
                id: 7,
                count: 4,
                min: 1
            }
        );
        assert!(e.to_string().contains("SLURM_ARRAY_TASK_ID=7"), "{e}");
        assert!(ok("0", "4", "1").is_err());
        assert!(ok("1", "0", "1").is_err());
        let e = ok("x", "4", "1").unwrap_err();
        assert!(matches!(
            e,
            AutoShardError::NotANumber {
                var: "SLURM_ARRAY_TASK_ID",
                ..
            }
        ));
        // Outside an array: the first missing variable is named.
        let e = Shard::from_slurm(env(&[("SLURM_ARRAY_TASK_ID", "1")])).unwrap_err();
        assert_eq!(e, AutoShardError::Missing("SLURM_ARRAY_TASK_COUNT"));
        assert!(e.to_string().contains("--shard K/N"), "{e}");
        let e = Shard::from_slurm(env(&[])).unwrap_err();
        assert_eq!(e, AutoShardError::Missing("SLURM_ARRAY_TASK_ID"));
    }

    #[test]
    fn parses_and_refuses() {
        assert_eq!("2/3".parse::<Shard>().unwrap(), Shard { k: 2, n: 3 });
        assert_eq!("1/1".parse::<Shard>().unwrap(), Shard::ALL);
        for bad in ["", "3", "0/3", "4/3", "1/0", "a/b", "1/2/3", "-1/3"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn shards_partition_the_images() {
        for n in 1..6u32 {
            for j in 0..50 {
                let owners = (1..=n).filter(|&k| Shard { k, n }.owns(j)).count();
                assert_eq!(owners, 1, "image {j} with {n} shards");
            }
        }
    }
}
