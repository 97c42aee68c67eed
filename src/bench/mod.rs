//! Accuracy benchmark: leveld against baseline methods on simulated drive suites.

pub mod accuracy;
pub mod baselines;
pub mod plots;
pub mod realistic;
pub mod stops;
pub mod suite;
