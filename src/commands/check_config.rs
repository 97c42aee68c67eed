//! `leveld check-config`: the config and its DBC, and what will be decoded.

use anyhow::Result;
use std::io::Write;

/// `leveld check-config`.
pub fn run(config: Option<&std::path::Path>) -> Result<i32> {
    use crate::daemon::inputs::{ACC, GYR, WHEELS};
    use crate::daemon::pipeline::Pipeline;
    let (cfg, db, src) = crate::daemon::load(config)?;
    let p = Pipeline::new(&cfg, &db)?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "config: {src}")?;
    writeln!(out, "DBC:    {}", db.path.display())?;
    writeln!(
        out,
        "input interfaces: {}; output on {}",
        cfg.can.input_interfaces.join(", "),
        cfg.can.output_interface
    )?;
    for (slot, m) in [(WHEELS, &cfg.wheels), (ACC, &cfg.acc), (GYR, &cfg.gyro)] {
        let c = p.input_codec(slot);
        writeln!(
            out,
            "{:6} <- {} (0x{:X}{}), signals {}, counter [{}]{}, checksum {:?} [{}]{}, timeout {:.0} ms",
            c.name,
            m.message,
            c.id,
            if c.extended { " ext" } else { "" },
            m.signals.join(" "),
            m.counter.join(" "),
            if m.check_counter {
                ""
            } else {
                " (not checked)"
            },
            m.checksum_kind,
            m.checksum.join(" "),
            if m.check_checksum {
                ""
            } else {
                " (not checked)"
            },
            c.timeout_s * 1000.0
        )?;
    }
    let o = p.output();
    writeln!(
        out,
        "output -> {} (0x{:X}) every {} ms and on change; actuator {:+.2}..{:+.2} deg; reference pitch {:+.3} deg",
        cfg.output.message,
        o.id,
        cfg.output.period_ms,
        cfg.leveling.actuator_min_deg,
        cfg.leveling.actuator_max_deg,
        cfg.leveling.reference_pitch_deg
    )?;
    writeln!(out, "state file: {}", cfg.state.path.display())?;
    writeln!(out, "ok")?;
    Ok(0)
}
