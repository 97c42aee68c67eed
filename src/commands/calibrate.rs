//! `leveld calibrate`: end-of-line calibration from the bus or a log.

use anyhow::Result;

/// `leveld calibrate`.
pub fn run(
    config: Option<&std::path::Path>,
    log: Option<&std::path::Path>,
    interface: Option<&str>,
    duration_s: f64,
    state: Option<&std::path::Path>,
    calibration: Option<&std::path::Path>,
    dry_run: bool,
) -> Result<i32> {
    use crate::daemon::{calibrate, pipeline::Pipeline};
    use anyhow::Context;
    calibrate::check_duration(duration_s)?;
    let (cfg, db, _) = crate::daemon::load(config)?;
    let mut p = Pipeline::new(&cfg, &db)?;
    let cal = match log {
        Some(path) => {
            let f = std::fs::File::open(path)
                .with_context(|| format!("cannot open log {}", path.display()))?;
            calibrate::from_log(
                &mut p,
                &mut std::io::BufReader::new(f),
                interface,
                duration_s,
            )?
        }
        None => crate::daemon::live::calibrate_live(&cfg, &mut p, duration_s)?,
    };
    cal.check_plausible()?;
    println!(
        "reference pitch {:+.3} deg, roll {:+.3} deg, from {:.1} s of standstill",
        cal.reference_pitch_deg, cal.reference_roll_deg, cal.settled_s
    );
    if !dry_run {
        let state_path = state.map_or_else(|| cfg.state.path.clone(), |p| p.to_path_buf());
        let cal_path =
            calibration.map_or_else(|| cfg.state.calibration_path.clone(), |p| p.to_path_buf());
        calibrate::store(&mut p, &cal_path, &state_path, &cal)?;
        println!(
            "stored in {}; estimate seeded in {}",
            cal_path.display(),
            state_path.display()
        );
    }
    Ok(0)
}
