//! The one frame loop: replay, calibrate and run fed the same frames agree, and the
//! daemon (`leveld run` without its sockets and signals) runs in-process on an
//! in-memory bus.

use leveld::can::candump::{Line, parse_line};
use leveld::can::codec::Status;
use leveld::daemon::config::Config;
use leveld::daemon::frame_loop::{MemoryBus, RxFrame};
use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::socket::SharedStats;
use leveld::daemon::state::{self, Loaded};
use leveld::daemon::{calibrate, live, replay};
use std::path::PathBuf;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

const LOG: &str = "data/sim-multi-stop.log";

/// The reference config with its state and status files in a fresh folder.
fn config(tag: &str) -> (Config, leveld::can::dbc::Database) {
    let (mut cfg, db, _) = leveld::daemon::load(Some(&root().join("config/leveld.toml"))).unwrap();
    let d = std::env::temp_dir().join(format!("leveld-loop-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    cfg.state.path = d.join("state.json");
    cfg.state.status_path = d.join("status.json");
    cfg.state.calibration_path = d.join("calibration.json");
    (cfg, db)
}

fn frames() -> Vec<RxFrame> {
    std::fs::read_to_string(root().join(LOG))
        .unwrap()
        .lines()
        .filter_map(|l| match parse_line(l) {
            Ok(Line::Frame(f)) => Some(RxFrame::data(f.t_s, f.id, f.extended, f.payload())),
            _ => None,
        })
        .collect()
}

/// `serve` (the daemon of `leveld run`) over `bus` until the bus is exhausted, then
/// shut down through its shutdown future, as SIGTERM does.
fn serve(cfg: &Config, p: &mut Pipeline, bus: MemoryBus) -> (i32, MemoryBus) {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let mut bus = bus.then_notify(tx);
    let code = rt
        .block_on(live::serve(
            cfg,
            p,
            &mut bus,
            SharedStats::default(),
            async {
                let _ = rx.await;
            },
        ))
        .unwrap();
    (code, bus)
}

#[test]
fn replay_run_and_calibrate_give_the_same_estimates_from_the_same_frames() {
    let (cfg, db) = config("same");
    // replay
    let mut p_replay = Pipeline::new(&cfg, &db).unwrap();
    // `leveld replay` runs with the config's calibration file, as the daemon does;
    // there is none in this folder.
    p_replay.set_calibration(&leveld::daemon::calibration::load(
        &cfg.state.calibration_path,
    ));
    let mut input = std::io::BufReader::new(std::fs::File::open(root().join(LOG)).unwrap());
    let (mut events, mut out) = (Vec::new(), Vec::new());
    let opts = replay::ReplayOptions::default();
    let summary = replay::replay(
        &mut p_replay,
        &mut input,
        &opts,
        &mut events,
        Some(&mut out),
    )
    .unwrap();
    let replayed: Vec<(f64, Vec<u8>)> = String::from_utf8(out)
        .unwrap()
        .lines()
        .map(|l| match parse_line(l).unwrap() {
            Line::Frame(f) => (f.t_s, f.payload().to_vec()),
            Line::Skip => panic!("replay wrote a non-frame line: {l}"),
        })
        .collect();
    assert!(summary.estimates_accepted >= 5, "{summary:?}");

    // run: the same frames, no idle ticks, ended by the shutdown future
    let mut p_run = Pipeline::new(&cfg, &db).unwrap();
    let (code, bus) = serve(&cfg, &mut p_run, MemoryBus::new(frames()));
    assert_eq!(code, 0);
    // Replay also evaluates what is pending at the end of its input; run does not.
    let mut sent: Vec<(f64, Vec<u8>)> = bus.sent.iter().map(|s| (s.0, s.3.to_vec())).collect();
    assert!(sent.len() > 2000, "{} frames", sent.len());
    assert!(replayed.len() >= sent.len());
    replayed[..sent.len()]
        .iter()
        .zip(&sent)
        .enumerate()
        .for_each(|(i, (r, s))| {
            assert!((r.0 - s.0).abs() < 2e-6, "frame {i}: {} vs {}", r.0, s.0);
            assert_eq!(r.1, s.1, "frame {i} at {}", r.0);
        });
    sent.clear();
    let (e_replay, e_run) = (p_replay.estimate().unwrap(), p_run.estimate().unwrap());
    assert_eq!(e_replay.windows, e_run.windows);
    assert_eq!(e_replay.road_to_body_deg, e_run.road_to_body_deg);
    assert_eq!(
        p_replay.counters().windows_accepted,
        p_run.counters().windows_accepted
    );

    // calibrate: stops at the first standstill settled for 2 s
    let mut p_cal = Pipeline::new(&cfg, &db).unwrap();
    let mut input = std::io::BufReader::new(std::fs::File::open(root().join(LOG)).unwrap());
    let cal = calibrate::from_log(&mut p_cal, &mut input, None, 2.0).unwrap();
    assert!(cal.settled_s >= 2.0, "{cal:?}");
    // ... and run over the frames up to that one is at the same standstill.
    let upto: Vec<RxFrame> = frames().into_iter().filter(|f| f.t_s <= cal.at_s).collect();
    let (cfg2, _) = config("same-cal");
    let mut p_upto = Pipeline::new(&cfg2, &db).unwrap();
    serve(&cfg2, &mut p_upto, MemoryBus::new(upto));
    assert_eq!(
        p_upto.standstill_pitch(),
        Some((cal.reference_pitch_deg, cal.settled_s))
    );
    assert_eq!(p_upto.estimate(), p_cal.estimate());
}

#[test]
fn run_in_process_sends_at_10_hz_holds_on_input_loss_and_saves_on_shutdown() {
    let (cfg, db) = config("run");
    // The bus falls silent for 3 s (a connector pulled): time goes on by the idle
    // ticks alone.
    let (loss_from, loss_to) = (1070.0, 1073.0);
    let input: Vec<RxFrame> = frames()
        .into_iter()
        .filter(|f| !(f.t_s >= loss_from && f.t_s < loss_to))
        .collect();
    let (first, last) = (input[0].t_s, input.last().unwrap().t_s);
    let mut p = Pipeline::new(&cfg, &db).unwrap();
    let (code, bus) = serve(&cfg, &mut p, MemoryBus::new(input).with_ticks(0.01, last));
    assert_eq!(code, 0, "state saved at shutdown");

    // 10 Hz on the frame clock, through the input loss as well
    let t: Vec<f64> = bus.sent.iter().map(|s| s.0).collect();
    let max_gap = t.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
    assert!(
        max_gap <= 0.1 + 1e-9,
        "largest gap between LEVELING frames {max_gap} s"
    );
    let periodic = ((last - first) / 0.1).floor() as usize;
    assert!(
        t.len() >= periodic,
        "{} frames over {} s",
        t.len(),
        last - first
    );

    let out = p.output().clone();
    let decoded: Vec<(f64, leveld::can::codec::LevelingFrame)> =
        bus.sent.iter().map(|s| (s.0, out.decode(&s.3))).collect();
    let at = |t_s: f64| {
        decoded
            .iter()
            .rev()
            .find(|d| d.0 <= t_s)
            .map(|d| d.1)
            .unwrap()
    };
    let before = at(loss_from - 0.05);
    assert!(before.estimate_count > 0 && before.status != Status::HoldInputLost as u64);
    // The input timeouts are 10 cycles (0.1-0.2 s): held from then until frames return.
    for (t_s, f) in decoded
        .iter()
        .filter(|d| d.0 > loss_from + 0.25 && d.0 < loss_to)
    {
        assert_eq!(f.status, Status::HoldInputLost as u64, "at {t_s}");
        assert_eq!(
            f.road_to_body_deg, before.road_to_body_deg,
            "value held at {t_s}"
        );
        assert!(f.crc_ok);
    }
    let after = at(loss_to + 0.5);
    assert_ne!(after.status, Status::HoldInputLost as u64, "recovered");

    // The state file holds the final estimate; the status file says it stopped.
    let est = p.estimate().unwrap();
    match state::read(&cfg.state.path) {
        Loaded::State(st) => {
            let mut q = Pipeline::new(&cfg, &db).unwrap();
            q.restore(&st.estimator).unwrap();
            assert_eq!(q.estimate().unwrap().windows, est.windows);
            assert_eq!(q.estimate().unwrap().road_to_body_deg, est.road_to_body_deg);
        }
        other => panic!("state file after shutdown: {other:?}"),
    }
    let status: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&cfg.state.status_path).unwrap()).unwrap();
    assert_eq!(status["running"], false);
    assert_eq!(status["windows"], est.windows);
    assert_eq!(status["last_save"]["ok"], true);
}

/// Issue reproducer: a state file that cannot be parsed used to take the factory
/// calibration with it, silently. The calibration now lives in its own file that the
/// daemon never writes; a missing one is flagged, an unreadable one is FAULT.
#[test]
fn the_calibration_survives_a_corrupt_state_file_and_is_never_silently_lost() {
    use leveld::daemon::calibration::{self, CalibrationFile};
    let first_10_s: Vec<RxFrame> = frames().into_iter().filter(|f| f.t_s < 1010.0).collect();
    let run = |cfg: &Config, db| {
        let mut p = Pipeline::new(cfg, db).unwrap();
        let (code, bus) = serve(cfg, &mut p, MemoryBus::new(first_10_s.clone()));
        let last = bus.sent.last().unwrap().3;
        let status: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&cfg.state.status_path).unwrap()).unwrap();
        (code, p.output().decode(&last), status)
    };

    let (cfg, db) = config("cal");
    let cal = CalibrationFile {
        format: CalibrationFile::FORMAT,
        reference_pitch_deg: 0.8,
        reference_roll_deg: None,
        settled_s: 30.0,
        written_unix_s: 1.8e9,
    };
    calibration::save(&cfg.state.calibration_path, &cal).unwrap();
    let cal_bytes = std::fs::read(&cfg.state.calibration_path).unwrap();
    for bad_state in [&b""[..], b"{\"format\":1,\"estim", b"null", b"\x00\xff"] {
        std::fs::write(&cfg.state.path, bad_state).unwrap();
        let (code, out, status) = run(&cfg, &db);
        assert_eq!(code, 0);
        assert_eq!(out.uncalibrated, Some(false), "state {bad_state:?}");
        assert_ne!(out.status, Status::Fault as u64);
        assert_eq!(status["reference_pitch_deg"], 0.8);
        assert_eq!(status["calibration"], "ok");
        assert_eq!(
            std::fs::read(&cfg.state.calibration_path).unwrap(),
            cal_bytes,
            "the daemon never rewrites the calibration"
        );
    }

    // No calibration: the configured reference, flagged.
    std::fs::remove_file(&cfg.state.calibration_path).unwrap();
    let (_, out, status) = run(&cfg, &db);
    assert_eq!(out.uncalibrated, Some(true));
    assert_ne!(out.status, Status::Fault as u64);
    assert!(
        status["calibration"]
            .as_str()
            .unwrap()
            .starts_with("missing")
    );
    assert!(
        !cfg.state.calibration_path.exists(),
        "not created by the daemon"
    );

    // An unreadable calibration: FAULT, flagged, the file left for a person.
    for bad in [
        &b""[..],
        b"null",
        b"{\"format\":1,\"reference_pitch_deg\":0.8}",
    ] {
        std::fs::write(&cfg.state.calibration_path, bad).unwrap();
        let (_, out, status) = run(&cfg, &db);
        assert_eq!(out.status, Status::Fault as u64, "calibration {bad:?}");
        assert_eq!(out.uncalibrated, Some(true));
        assert_eq!(status["status"], "FAULT");
        assert!(
            status["calibration"]
                .as_str()
                .unwrap()
                .starts_with("unreadable")
        );
        assert_eq!(std::fs::read(&cfg.state.calibration_path).unwrap(), bad);
    }
}
