//! `leveld replay`: a candump log through the pipeline.

use anyhow::Result;
use std::io::Write;

/// `leveld replay`.
pub fn run(
    input: &std::path::Path,
    config: Option<&std::path::Path>,
    output: Option<&std::path::Path>,
    interface: Option<String>,
    json: bool,
    strict: bool,
    calibration: Option<&std::path::Path>,
) -> Result<i32> {
    use crate::daemon::{pipeline::Pipeline, replay};
    use anyhow::Context;
    let (cfg, db, _src) = crate::daemon::load(config)?;
    let mut p = Pipeline::new(&cfg, &db)?;
    // With --calibration, that file's reference pitch, as the daemon would read it;
    // without, the config's, flagged uncalibrated. A replay never depends on the
    // files of the machine it runs on.
    p.set_calibration(&match calibration {
        Some(path) => crate::daemon::calibration::load(path),
        None => crate::daemon::calibration::Calibration::Missing,
    });
    let mut reader: Box<dyn std::io::BufRead> = if input.as_os_str() == "-" {
        Box::new(std::io::stdin().lock())
    } else {
        let f = std::fs::File::open(input)
            .with_context(|| format!("cannot open log {}", input.display()))?;
        Box::new(std::io::BufReader::with_capacity(1 << 16, f))
    };
    let mut frames_out = match output {
        Some(o) => Some(std::io::BufWriter::new(
            std::fs::File::create(o).with_context(|| format!("cannot create {}", o.display()))?,
        )),
        None => None,
    };
    let opts = replay::ReplayOptions {
        interface,
        strict,
        json,
        output_interface: cfg.can.output_interface.clone(),
    };
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let summary = replay::replay(
        &mut p,
        &mut reader,
        &opts,
        &mut out,
        frames_out.as_mut().map(|w| w as &mut dyn Write),
    )
    .with_context(|| format!("replaying {}", input.display()))?;
    if let Some(w) = frames_out.as_mut() {
        w.flush().context("writing the output log")?;
    }
    if json {
        writeln!(out, "{}", serde_json::json!({ "summary": summary }))?;
    } else {
        replay::write_summary_text(&mut out, &summary)?;
    }
    out.flush()?;
    Ok(0)
}
