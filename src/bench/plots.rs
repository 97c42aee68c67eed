//! Plots of the accuracy benchmark (not yet drawn; see README).

use super::accuracy::Row;

pub fn write(_dir: &std::path::Path, _rows: &[Row]) -> anyhow::Result<()> {
    anyhow::bail!("--plots is not available yet")
}
