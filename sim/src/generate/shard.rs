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

#[cfg(test)]
mod tests {
    use super::*;

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
