//! Throughput figures: `cargo bench --bench throughput`.
//!
//! - estimator: IMU samples per second on one core, over simulated multi-stop drives;
//! - replay: candump lines per second through parse + pipeline on a log of more than
//!   a million frames, and the same log parsed and decoded by python-can + cantools
//!   as a peer, measured in the same run.

use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::replay::{ReplayOptions, replay};
use leveld::estimator::{Estimator, EstimatorConfig};
use leveld::sim::canlog::{InputEncoder, write_candump};
use leveld::sim::{Input, presets, simulate};
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));

    // Estimator alone.
    let drives: Vec<_> = (1..=4)
        .map(|s| simulate(&presets::preset("multi-stop", s).unwrap()))
        .collect();
    let inputs: Vec<Vec<Input>> = drives.iter().map(|d| d.merged().collect()).collect();
    let imu_samples: usize = drives.iter().map(|d| d.imu.len()).sum();
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t = Instant::now();
        let mut windows = 0u64;
        for inp in &inputs {
            let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
            let mut count = |e: leveld::estimator::Event| {
                if matches!(e, leveld::estimator::Event::WindowAccepted { .. }) {
                    windows += 1;
                }
            };
            for i in inp {
                match *i {
                    Input::Imu(s) => est.push_imu(s, &mut count),
                    Input::Wheels(w) => est.push_wheels(w, &mut count),
                }
            }
        }
        std::hint::black_box(windows);
        best = best.min(t.elapsed().as_secs_f64());
    }
    println!(
        "estimator: {:.2} M IMU samples/s on one core ({} samples, {:.1} h of driving per second of CPU)",
        imu_samples as f64 / best / 1e6,
        imu_samples,
        imu_samples as f64 / best / 100.0 / 3600.0
    );

    // A log of more than a million frames: 20 drives back to back.
    let db = leveld::can::dbc::Database::load(&root.join("dbc/leveld.dbc")).unwrap();
    let mut log = Vec::new();
    let mut t0 = 1000.0;
    let mut frames = 0u64;
    for seed in 0..20 {
        let sc = presets::preset("multi-stop", 100 + seed).unwrap();
        let d = simulate(&sc);
        let mut enc = InputEncoder::new(&db).unwrap();
        frames += write_candump(&d, &mut enc, "can0", t0, &mut log).unwrap();
        t0 += sc.speed.duration_s() + 1.0;
    }
    let path = root.join("target/bench-replay.log");
    std::fs::write(&path, &log).unwrap();
    let (cfg, db, _) = leveld::daemon::load(Some(&root.join("config/leveld.toml"))).unwrap();
    let mut best = f64::MAX;
    let mut accepted = 0;
    for _ in 0..3 {
        let mut p = Pipeline::new(&cfg, &db).unwrap();
        let t = Instant::now();
        let s = replay(
            &mut p,
            &mut &log[..],
            &ReplayOptions::default(),
            &mut std::io::sink(),
            Some(&mut std::io::sink()),
        )
        .unwrap();
        best = best.min(t.elapsed().as_secs_f64());
        accepted = s.estimates_accepted;
    }
    let ours = frames as f64 / best;
    println!(
        "replay: {:.2} M frames/s ({} frames, {} windows accepted, {:.1} MB/s of log)",
        ours / 1e6,
        frames,
        accepted,
        log.len() as f64 / best / 1e6
    );

    // Peer: python-can reads the same file, cantools decodes the three input messages.
    let peer = r#"
import sys, time
import can, cantools
db = cantools.database.load_file(sys.argv[1])
msgs = {m.frame_id: m for m in db.messages if m.name in ("WHL_SPD11", "IMU_ACC", "IMU_GYR")}
t = time.perf_counter()
n = 0
for msg in can.CanutilsLogReader(sys.argv[2]):
    m = msgs.get(msg.arbitration_id)
    if m is not None:
        m.decode(msg.data)
    n += 1
print(n, time.perf_counter() - t)
"#;
    match std::process::Command::new("python3")
        .arg("-c")
        .arg(peer)
        .arg(root.join("dbc/leveld.dbc"))
        .arg(&path)
        .output()
    {
        Ok(o) if o.status.success() => {
            let out = String::from_utf8_lossy(&o.stdout);
            let mut it = out.split_whitespace();
            let n: f64 = it.next().and_then(|x| x.parse().ok()).unwrap_or(0.0);
            let secs: f64 = it.next().and_then(|x| x.parse().ok()).unwrap_or(f64::NAN);
            println!(
                "peer (python-can read + cantools decode): {:.3} M frames/s; leveld replay is {:.0}x faster while also running the estimator",
                n / secs / 1e6,
                ours / (n / secs)
            );
        }
        Ok(o) => println!(
            "peer unavailable: {}",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .last()
                .unwrap_or("")
        ),
        Err(e) => println!("peer unavailable: {e}"),
    }
}
