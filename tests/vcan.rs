//! End-to-end tests on a virtual CAN bus: the real `leveld run` binary, fed by
//! can-utils' `canplayer`, recorded by `candump -L`.
//!
//! They need SocketCAN and root, so they are `#[ignore]` in a plain `cargo test`.
//! `tools/test-all.sh` runs them through `tools/vcan-vm.sh`, which provides a kernel
//! with vcan (this machine's, or a small VM's), with `--ignored --test-threads=1`.

// Signals to the daemon and the tools under test go through libc::kill.
#![allow(unsafe_code)]

use leveld::can::candump::{CandumpLine, Line, LogFrame, parse_line};
use leveld::can::codec::{LevelingFrame as Leveling, OutputCodec, Status};
use leveld::sim::canlog::{InputEncoder, write_candump};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const IFACE: &str = "vcan0";
const TRUTH_DEG: f64 = 0.6; // load pitch of the "short" preset

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn sh(cmd: &str, args: &[&str]) -> bool {
    Command::new(cmd)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A vcan interface, created fresh and deleted at the end.
struct Vcan;

impl Vcan {
    fn up() -> Self {
        sh("ip", &["link", "del", IFACE]);
        assert!(
            sh("ip", &["link", "add", "dev", IFACE, "type", "vcan"]),
            "cannot create {IFACE}: run through tools/vcan-vm.sh"
        );
        assert!(sh("ip", &["link", "set", "up", IFACE]));
        Vcan
    }
}

impl Drop for Vcan {
    fn drop(&mut self) {
        sh("ip", &["link", "del", IFACE]);
    }
}

fn workdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("leveld-vcan-{tag}"));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A config for vcan0 with its state file in `dir`.
fn config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("config/leveld.toml"))
        .unwrap()
        .replace(
            "input_interfaces = [\"can0\"]",
            &format!("input_interfaces = [\"{IFACE}\"]"),
        )
        .replace(
            "output_interface = \"can0\"",
            &format!("output_interface = \"{IFACE}\""),
        )
        .replace(
            "dbc = \"../dbc/leveld.dbc\"",
            &format!("dbc = \"{}\"", root().join("dbc/leveld.dbc").display()),
        )
        .replace(
            "path = \"/var/lib/leveld/state.json\"",
            "path = \"state.json\"",
        );
    let p = dir.join("leveld.toml");
    std::fs::write(&p, text).unwrap();
    p
}

struct Leveld {
    child: Child,
    log: PathBuf,
}

impl Leveld {
    fn start(dir: &Path, tag: &str) -> Self {
        let log = dir.join(format!("leveld-{tag}.log"));
        let child = Command::new(env!("CARGO_BIN_EXE_leveld"))
            .args(["run", "--config"])
            .arg(config(dir))
            .env("LEVELD_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        let me = Leveld { child, log };
        me.wait_log("CAN open", 1, Duration::from_secs(20));
        me
    }

    fn text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    fn wait_log(&self, needle: &str, count: usize, limit: Duration) {
        let t = Instant::now();
        while self.text().matches(needle).count() < count {
            assert!(
                t.elapsed() < limit,
                "leveld never logged {needle:?} ({count}x):\n{}",
                self.text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn pid(&self) -> i32 {
        self.child.id() as i32
    }

    /// SIGTERM, then the exit code.
    fn term(mut self) -> (i32, String) {
        unsafe { libc::kill(self.pid(), libc::SIGTERM) };
        let code = wait(&mut self.child, Duration::from_secs(20));
        (code, self.text())
    }

    fn kill9(mut self) {
        unsafe { libc::kill(self.pid(), libc::SIGKILL) };
        wait(&mut self.child, Duration::from_secs(20));
    }

    /// Frames the daemon could not send although the interface was open.
    fn queue_full(text: &str) -> u64 {
        Self::final_stats(text)["send_queue_full"].as_u64().unwrap()
    }

    fn final_stats(text: &str) -> serde_json::Value {
        let line = text
            .lines()
            .find(|l| l.contains("final stats "))
            .unwrap_or_else(|| panic!("no final stats in:\n{text}"));
        serde_json::from_str(line.split("final stats ").nth(1).unwrap().trim()).unwrap()
    }
}

fn wait(child: &mut Child, limit: Duration) -> i32 {
    let t = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st.code().unwrap_or(-1);
        }
        assert!(t.elapsed() < limit, "process did not exit");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `candump -L` of `filter` on vcan0 into a file.
struct Candump {
    child: Child,
    path: PathBuf,
}

impl Candump {
    fn start(path: PathBuf, filter: &str) -> Self {
        let spec = if filter.is_empty() {
            IFACE.to_string()
        } else {
            format!("{IFACE},{filter}")
        };
        // -d: candump reports the frames its socket dropped ("DROPCOUNT" lines).
        let child = Command::new("candump")
            .args(["-d", "-L", &spec])
            .stdout(std::fs::File::create(&path).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .expect("candump (can-utils) must be installed");
        std::thread::sleep(Duration::from_millis(300));
        Candump { child, path }
    }

    fn stop(self) -> Vec<LogFrame> {
        self.stop_with_drops().0
    }

    /// The frames, and how many candump's socket dropped.
    fn stop_with_drops(mut self) -> (Vec<LogFrame>, u64) {
        std::thread::sleep(Duration::from_millis(300));
        unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        wait(&mut self.child, Duration::from_secs(10));
        let text = std::fs::read_to_string(&self.path).unwrap();
        // "DROPCOUNT: dropped 2 CAN frames on 'vcan0' socket (total drops 5)"
        let drops = text
            .lines()
            .filter_map(|l| l.split("(total drops ").nth(1))
            .filter_map(|r| r.trim_end_matches(')').trim().parse::<u64>().ok())
            .max()
            .unwrap_or(0);
        (frames_of(&text), drops)
    }
}

fn read_frames(path: &Path) -> Vec<LogFrame> {
    frames_of(&std::fs::read_to_string(path).unwrap())
}

/// The frames of candump log text; other lines (candump's own reports) are skipped.
fn frames_of(text: &str) -> Vec<LogFrame> {
    text.lines()
        .filter_map(|l| match parse_line(l) {
            Ok(Line::Frame(f)) => Some(f),
            _ => None,
        })
        .collect()
}

fn canplayer(log: &Path, map: Option<&str>) {
    let mut c = Command::new("canplayer");
    c.arg("-I").arg(log);
    if let Some(m) = map {
        c.arg(m);
    }
    let st = c.status().expect("canplayer (can-utils) must be installed");
    assert!(st.success(), "canplayer failed");
}

/// The "short" drive as candump lines on vcan0, filtered by relative time.
fn drive_log(dir: &Path, name: &str, keep: impl Fn(&LogFrame, f64) -> bool) -> PathBuf {
    let sc = leveld::sim::presets::preset("short", 1).unwrap();
    let drive = leveld::sim::simulate(&sc);
    let db = leveld::can::dbc::Database::load(&root().join("dbc/leveld.dbc")).unwrap();
    let mut enc = InputEncoder::new(&db).unwrap();
    let mut raw = Vec::new();
    write_candump(&drive, &mut enc, IFACE, 0.0, &mut raw).unwrap();
    let mut out = String::new();
    for l in String::from_utf8(raw).unwrap().lines() {
        if let Ok(Line::Frame(f)) = parse_line(l)
            && keep(&f, f.t_s)
        {
            out.push_str(&format!("{}\n", CandumpLine(&f)));
        }
    }
    let p = dir.join(name);
    std::fs::write(&p, out).unwrap();
    p
}

fn output_codec() -> OutputCodec {
    let (cfg, db, _) = leveld::daemon::load(Some(&root().join("config/leveld.toml"))).unwrap();
    leveld::daemon::pipeline::Pipeline::new(&cfg, &db)
        .unwrap()
        .output()
        .clone()
}

fn decode(out: &OutputCodec, f: &LogFrame) -> Leveling {
    out.decode(&f.payload().try_into().expect("LEVELING has 8 bytes"))
}

fn status(l: &Leveling) -> Status {
    Status::from_raw(l.status).expect("valid status value")
}

/// Every frame carries a valid CRC, and the alive counter steps by one from frame to
/// frame except where a frame was lost on the way: `lost` is what the two ends
/// counted (the daemon's full send queue, candump's dropped frames).
fn check_counter_and_crc(out: &OutputCodec, frames: &[LogFrame], lost: u64) {
    assert!(frames.len() > 20);
    let mut missing = 0u64;
    for w in frames.windows(2) {
        let (a, b) = (decode(out, &w[0]), decode(out, &w[1]));
        let gap = (b.counter + 16 - a.counter - 1) % 16;
        missing += gap;
        assert!(
            missing <= lost,
            "counter {} -> {} at {}: {missing} frames missing, {lost} counted as lost",
            a.counter,
            b.counter,
            w[1].t_s
        );
    }
    for f in frames {
        assert!(decode(out, f).crc_ok, "CRC at {}", f.t_s);
    }
}

/// Periodic LEVELING frames per second over [t0, t1]. On-change frames are the ones
/// whose content (all but counter and CRC) differs from the frame before.
fn periodic_rate(frames: &[LogFrame], t0: f64, t1: f64) -> f64 {
    let content = |f: &LogFrame| f.payload()[..6].to_vec();
    let mut n = 0usize;
    let mut changes = 0usize;
    for (i, f) in frames.iter().enumerate() {
        if f.t_s < t0 || f.t_s > t1 {
            continue;
        }
        n += 1;
        if i > 0 && content(&frames[i - 1]) != content(f) {
            changes += 1;
        }
    }
    (n - changes) as f64 / (t1 - t0)
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t1_simulated_drive_on_the_bus_converges_to_truth_and_matches_replay() {
    let dir = workdir("drive");
    let _bus = Vcan::up();
    let log = drive_log(&dir, "drive.log", |_, _| true);
    let d = Leveld::start(&dir, "run");
    let outputs = Candump::start(dir.join("out.log"), "3E8:7FF");
    let inputs = Candump::start(dir.join("in.log"), "");
    canplayer(&log, None);
    let (out_frames, out_drops) = outputs.stop_with_drops();
    let in_frames: Vec<LogFrame> = inputs
        .stop()
        .into_iter()
        .filter(|f| f.id != 0x3E8)
        .collect();
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let out = output_codec();
    check_counter_and_crc(&out, &out_frames, Leveld::queue_full(&text) + out_drops);
    let (t_in0, t_in1) = (
        in_frames.first().unwrap().t_s,
        in_frames.last().unwrap().t_s,
    );
    // 10 Hz within 10 % over the drive.
    let rate = periodic_rate(&out_frames, t_in0 + 1.0, t_in1 - 1.0);
    assert!((9.0..=11.0).contains(&rate), "LEVELING at {rate:.2} Hz");
    // While inputs flow: NO_ESTIMATE -> CONVERGING -> VALID. Only a stall of canplayer
    // itself (a silence on the bus, seen in the inputs' capture) may hold the value as
    // HOLD_INPUT_LOST, once per stall.
    let live: Vec<(f64, Leveling)> = out_frames
        .iter()
        .filter(|f| f.t_s > t_in0 + 0.5 && f.t_s < t_in1)
        .map(|f| (f.t_s, decode(&out, f)))
        .collect();
    let statuses: Vec<Status> = live.iter().map(|(_, l)| status(l)).collect();
    let stalls = bus_silences(&in_frames);
    assert!(
        hold_episodes(&statuses) <= stalls,
        "{} stretches of HOLD_INPUT_LOST, {stalls} silences of the feed",
        hold_episodes(&statuses)
    );
    let mut seq: Vec<Status> = Vec::new();
    for &st in statuses.iter().filter(|&&st| st != Status::HoldInputLost) {
        if seq.last() != Some(&st) {
            seq.push(st);
        }
    }
    assert_eq!(
        seq,
        vec![Status::NoEstimate, Status::Converging, Status::Valid],
        "{seq:?}"
    );
    let last = live.last().unwrap().1;
    assert!(
        (last.road_to_body_deg - TRUTH_DEG).abs() < 0.2,
        "final {} vs truth {TRUTH_DEG}",
        last.road_to_body_deg
    );
    // `leveld replay` of the inputs as the bus delivered them gives the same estimates
    // in the same order.
    let rec = dir.join("in-only.log");
    std::fs::write(
        &rec,
        in_frames
            .iter()
            .map(|f| format!("{}\n", CandumpLine(f)))
            .collect::<String>(),
    )
    .unwrap();
    let replay_out = dir.join("replay-out.log");
    let st = Command::new(env!("CARGO_BIN_EXE_leveld"))
        .args(["replay", "--config"])
        .arg(config(&dir))
        .arg(&rec)
        .arg("--output")
        .arg(&replay_out)
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(st.success());
    let key = |l: &Leveling| {
        (
            l.road_to_body_deg.to_bits(),
            l.estimate_count,
            l.road_slope_deg.to_bits(),
        )
    };
    let distinct = |v: Vec<Leveling>| {
        let mut d: Vec<(u64, u64, u64)> = Vec::new();
        for l in v.iter().filter(|l| l.estimate_count > 0) {
            if d.last() != Some(&key(l)) {
                d.push(key(l));
            }
        }
        d
    };
    let live_est = distinct(live.iter().map(|(_, l)| *l).collect());
    let replay_est = distinct(
        read_frames(&replay_out)
            .iter()
            .map(|f| decode(&out, f))
            .collect(),
    );
    assert!(live_est.len() >= 8, "{live_est:?}");
    assert_eq!(live_est, replay_est, "live and replay estimates differ");
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t2_real_kona_capture_mapped_onto_vcan() {
    let dir = workdir("kona");
    let _bus = Vcan::up();
    let d = Leveld::start(&dir, "run");
    canplayer(
        &root().join("tests/data/kona-ev-2019-ccan-power-cycle.log"),
        Some("vcan0=can1"),
    );
    std::thread::sleep(Duration::from_millis(500));
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let s = Leveld::final_stats(&text);
    let w = &s["messages"]["WHL_SPD11"];
    assert_eq!(w["frames"], 542, "{s}");
    assert_eq!(
        (
            w["checksum_errors"].as_u64(),
            w["counter_errors"].as_u64(),
            w["dlc_errors"].as_u64()
        ),
        (Some(0), Some(0), Some(0)),
        "{s}"
    );
    assert!(
        text.contains("wheels stopped"),
        "standstill must be detected:\n{text}"
    );
    assert_eq!(s["windows_accepted"], 0, "the car never moves");
    assert_eq!(s["status"], "HOLD_INPUT_LOST", "no IMU on that bus: {s}");
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t3_imu_loss_holds_the_last_value_and_recovers() {
    let dir = workdir("imuloss");
    let _bus = Vcan::up();
    // The first 55 s of the drive with no IMU frames from 40 s to 43 s.
    let log = drive_log(&dir, "gap.log", |f, t| {
        t < 55.0 && !(f.id != 0x386 && t > 40.0 && t < 43.0)
    });
    let d = Leveld::start(&dir, "run");
    let rec = Candump::start(dir.join("all.log"), "");
    canplayer(&log, None);
    let all = rec.stop();
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let out = output_codec();
    let lv: Vec<&LogFrame> = all.iter().filter(|f| f.id == 0x3E8).collect();
    let imu: Vec<f64> = all
        .iter()
        .filter(|f| f.id == 0x3E0)
        .map(|f| f.t_s)
        .collect();
    let gap = imu
        .windows(2)
        .find(|w| w[1] - w[0] > 2.0)
        .expect("the IMU gap must be on the bus");
    let (t_stop, t_back) = (gap[0], gap[1]);
    let before = lv
        .iter()
        .rev()
        .find(|f| f.t_s < t_stop)
        .map(|f| decode(&out, f))
        .unwrap();
    let first_hold = lv
        .iter()
        .find(|f| f.t_s > t_stop && status(&decode(&out, f)) == Status::HoldInputLost)
        .expect("HOLD_INPUT_LOST");
    // 100 ms timeout, up to one output period, and scheduling slack.
    assert!(
        first_hold.t_s - t_stop <= 0.3,
        "HOLD after {:.3} s",
        first_hold.t_s - t_stop
    );
    for f in lv
        .iter()
        .filter(|f| f.t_s > first_hold.t_s && f.t_s < t_back)
    {
        let l = decode(&out, f);
        assert_eq!(status(&l), Status::HoldInputLost, "at {}", f.t_s);
        assert_eq!(
            l.road_to_body_deg, before.road_to_body_deg,
            "the last value is held"
        );
    }
    let recovered = lv
        .iter()
        .find(|f| f.t_s > t_back && status(&decode(&out, f)) != Status::HoldInputLost)
        .expect("recovery");
    assert!(
        recovered.t_s - t_back < 0.5,
        "recovered after {:.3} s",
        recovered.t_s - t_back
    );
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t4_interface_loss_reconnects_without_restart() {
    let dir = workdir("ifloss");
    let bus = Vcan::up();
    let part1 = drive_log(&dir, "p1.log", |_, t| t < 8.0);
    let part2 = drive_log(&dir, "p2.log", |_, t| (20.0..26.0).contains(&t));
    let d = Leveld::start(&dir, "run");
    let pid = d.pid();
    canplayer(&part1, None);
    assert!(sh("ip", &["link", "del", IFACE]));
    d.wait_log("CAN lost", 1, Duration::from_secs(10));
    std::thread::sleep(Duration::from_secs(1));
    drop(bus);
    let _bus = Vcan::up();
    d.wait_log("CAN open", 2, Duration::from_secs(20));
    let rec = Candump::start(dir.join("after.log"), "3E8:7FF");
    canplayer(&part2, None);
    let (after, drops) = rec.stop_with_drops();
    assert_eq!(d.pid(), pid);
    let (code, text) = d.term();
    assert_eq!(
        code, 0,
        "leveld must still be the same running process:\n{text}"
    );
    assert!(
        after.len() >= 40,
        "LEVELING after the interface came back: {}",
        after.len()
    );
    check_counter_and_crc(&output_codec(), &after, Leveld::queue_full(&text) + drops);
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t5_garbage_and_a_flood_are_counted_and_output_keeps_10_hz() {
    let dir = workdir("garbage");
    let _bus = Vcan::up();
    // The unbounded flood below starves the machine for a few seconds and may cost
    // the stop it lands on (the inputs time out); the drive runs on to a third stop
    // and drive-off well after it, so that "still estimated" does not hinge on where
    // the flood lands.
    let log = drive_log(&dir, "drive.log", |_, t| t < 44.0);
    let d = Leveld::start(&dir, "run");
    let rec = Candump::start(dir.join("out.log"), "3E8:7FF");
    let player = Command::new("canplayer")
        .arg("-I")
        .arg(&log)
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(8));
    // Wrong DLC, a bad CRC, and a repeated (valid) IMU frame for the counter check.
    for f in ["386#0000", "3E0#0102030405060708", "3E1#00"] {
        assert!(sh("cansend", &[IFACE, f]));
    }
    // A full 500 kbit/s bus: random frames every 0.25 ms (about 4000 frames/s) for 4 s.
    let (t0, t1) = (now(), now() + 4.0);
    let mut flood = Command::new("cangen")
        .args([IFACE, "-g", "0.25", "-I", "r", "-L", "r", "-D", "r"])
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(4));
    unsafe { libc::kill(flood.id() as i32, libc::SIGINT) };
    wait(&mut flood, Duration::from_secs(10));
    // Then an unbounded vcan flood (far beyond any real bus, it starves the whole
    // machine): leveld must survive it and be back at 10 Hz right after.
    let mut flood = Command::new("cangen")
        .args([IFACE, "-g", "0", "-I", "r", "-L", "r", "-D", "r"])
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(2));
    unsafe { libc::kill(flood.id() as i32, libc::SIGINT) };
    wait(&mut flood, Duration::from_secs(10));
    let t_after = now();
    let mut player = player;
    wait(&mut player, Duration::from_secs(60));
    // cangen's random IDs include 0x3E8: keep leveld's own frames, those with 8 bytes,
    // a valid CRC and the next alive counter.
    let out = output_codec();
    let mut out_frames: Vec<LogFrame> = Vec::new();
    for f in rec.stop() {
        if f.len != 8 || !decode(&out, &f).crc_ok {
            continue;
        }
        let next = out_frames
            .last()
            .map(|p| (decode(&out, p).counter + 1) % 16);
        if next.is_none_or(|c| c == decode(&out, &f).counter) {
            out_frames.push(f);
        }
    }
    let (code, text) = d.term();
    assert_eq!(code, 0, "no crash:\n{text}");
    let s = Leveld::final_stats(&text);
    assert!(
        s["messages"]["WHL_SPD11"]["dlc_errors"].as_u64().unwrap() >= 1,
        "{s}"
    );
    assert!(
        s["messages"]["IMU_ACC"]["checksum_errors"]
            .as_u64()
            .unwrap()
            >= 1,
        "{s}"
    );
    assert!(
        s["messages"]["IMU_GYR"]["dlc_errors"].as_u64().unwrap() >= 1,
        "{s}"
    );
    assert!(
        s["windows_accepted"].as_u64().unwrap() >= 2,
        "the drive must still be estimated: {s}"
    );
    let count_at = |t: f64| {
        out_frames
            .iter()
            .take_while(|f| f.t_s <= t)
            .last()
            .map_or(0, |f| decode(&out, f).estimate_count)
    };
    assert!(
        count_at(f64::INFINITY) > count_at(t_after),
        "no window accepted after the vcan flood: {s}"
    );
    let rate = periodic_rate(&out_frames, t0 + 0.2, t1 - 0.2);
    assert!(
        (9.0..=11.0).contains(&rate),
        "LEVELING at {rate:.2} Hz during the flood; {s}"
    );
    let rate_after = periodic_rate(&out_frames, t_after + 1.0, t_after + 6.0);
    assert!(
        (9.0..=11.0).contains(&rate_after),
        "LEVELING at {rate_after:.2} Hz after the vcan flood"
    );
    // out_frames keeps only the frames that continue the counter: nothing is missing.
    check_counter_and_crc(&output_codec(), &out_frames, 0);
}

fn now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t6_sigterm_saves_state_and_kill9_restart_restores_the_last_estimate() {
    let dir = workdir("crash");
    let _bus = Vcan::up();
    // SIGTERM after part of a drive: exit 0 with the state on disk.
    let part1 = drive_log(&dir, "p1.log", |_, t| t < 45.0);
    let d = Leveld::start(&dir, "a");
    canplayer(&part1, None);
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let saved: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("state.json")).unwrap()).unwrap();
    assert!(
        saved["estimator"]["averager"]["accepted"].as_u64().unwrap() >= 3,
        "{saved}"
    );
    // Start again, drive on, kill -9 mid-drive.
    let part2 = drive_log(&dir, "p2.log", |_, t| (45.0..75.0).contains(&t));
    let d = Leveld::start(&dir, "b");
    let rec = Candump::start(dir.join("before-kill.log"), "3E8:7FF");
    canplayer(&part2, None);
    let log_b = d.log.clone();
    d.kill9();
    let before = rec.stop();
    let text_b = std::fs::read_to_string(&log_b).unwrap_or_default();
    let out = output_codec();
    let last = decode(&out, before.last().unwrap());
    assert!(last.estimate_count >= 5, "{last:?}\n{text_b}");
    // Restart: the saved estimate comes out at once, with its status.
    let rec = Candump::start(dir.join("after-restart.log"), "3E8:7FF");
    let d = Leveld::start(&dir, "c");
    std::thread::sleep(Duration::from_millis(800));
    let after = rec.stop();
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let first = decode(&out, after.first().expect("output after restart"));
    assert_eq!(first.road_to_body_deg, last.road_to_body_deg);
    assert_eq!(first.estimate_count, last.estimate_count);
    assert!(
        matches!(status(&first), Status::Converging | Status::Valid),
        "{first:?}"
    );
    // With no inputs on the bus it then holds that value as HOLD_INPUT_LOST.
    let later = decode(&out, after.last().unwrap());
    assert_eq!(status(&later), Status::HoldInputLost);
    assert_eq!(later.road_to_body_deg, last.road_to_body_deg);
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t7_cantools_decodes_the_live_output_as_leveld_does() {
    let dir = workdir("cantools");
    let _bus = Vcan::up();
    let log = drive_log(&dir, "drive.log", |_, t| t < 25.0);
    let d = Leveld::start(&dir, "run");
    let rec = Candump::start(dir.join("out.log"), "3E8:7FF");
    canplayer(&log, None);
    let frames = rec.stop();
    let (code, _) = d.term();
    assert_eq!(code, 0);
    let script = r#"
import sys, json, cantools
db = cantools.database.load_file(sys.argv[1], strict=True)
m = db.get_message_by_name('LEVELING')
for line in open(sys.argv[2]):
    d = m.decode(bytes.fromhex(line.split('#')[1].split()[0]), decode_choices=False)
    print(json.dumps([d[k] for k in ('RoadToBodyPitch', 'LevelCorrection', 'RoadSlope', 'EstimateCount', 'Status', 'Counter', 'CRC')]))
"#;
    let o = Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(root().join("dbc/leveld.dbc"))
        .arg(dir.join("out.log"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let theirs: Vec<Vec<f64>> = String::from_utf8(o.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let out = output_codec();
    assert_eq!(theirs.len(), frames.len());
    assert!(frames.len() > 150);
    for (t, f) in theirs.iter().zip(&frames) {
        let l = decode(&out, f);
        let ours = [
            l.road_to_body_deg,
            l.level_correction_deg,
            l.road_slope_deg,
            l.estimate_count as f64,
            l.status as f64,
            l.counter as f64,
            l.crc as f64,
        ];
        for (a, b) in t.iter().zip(ours) {
            assert!((a - b).abs() < 1e-9, "{t:?} vs {ours:?}");
        }
    }
}

/// A pause of the test's own feed this long is an input loss the daemon must report
/// (the IMU times out after 100 ms), s.
const FEED_STALL_S: f64 = 0.08;

/// Play `frames` onto `IFACE` paced by the monotonic clock (canplayer paces by the
/// wall clock, which t8 steps). Returns how often the feed itself stalled: two
/// frames sent `FEED_STALL_S` or more further apart than their stamps. A stall that
/// long is an input loss the daemon must report (the IMU times out after 100 ms), so
/// the callers allow one loss per stall and no more; under software emulation the
/// player thread is sometimes not scheduled for that long.
fn play_monotonic(frames: &[LogFrame]) -> u64 {
    use socketcan::{CanFrame, EmbeddedFrame, Socket};
    let sock = socketcan::CanSocket::open(IFACE).expect("open vcan0");
    let (t0, start) = (frames[0].t_s, Instant::now());
    let mut stalls = 0;
    let mut prev: Option<(f64, Instant)> = None;
    for f in frames {
        let due = start + Duration::from_secs_f64(f.t_s - t0);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let frame = CanFrame::new(EmbeddedFrame::id(f), EmbeddedFrame::data(f)).unwrap();
        sock.write_frame(&frame).expect("write to vcan0");
        let sent = Instant::now();
        if let Some((t_prev, sent_prev)) = prev
            && (sent - sent_prev).as_secs_f64() - (f.t_s - t_prev) >= FEED_STALL_S
        {
            stalls += 1;
        }
        prev = Some((f.t_s, sent));
    }
    stalls
}

/// Silences of `FEED_STALL_S` or more between consecutive input frames on the bus (the
/// capture's own stamps): a feed at 100 Hz (IMU) and 50 Hz (wheels) has none, so each
/// is a stall of the player.
fn bus_silences(inputs: &[LogFrame]) -> u64 {
    inputs
        .windows(2)
        .filter(|w| w[1].t_s - w[0].t_s >= FEED_STALL_S)
        .count() as u64
}

/// LEVELING frames sent while the inputs flowed, in capture order (after a wall-clock
/// step the stamps jump), the first five left out.
fn outputs_while_inputs_flow(all: &[LogFrame]) -> Vec<LogFrame> {
    let first_in = all.iter().position(|f| f.id != 0x3E8).unwrap();
    let last_in = all.iter().rposition(|f| f.id != 0x3E8).unwrap();
    all[first_in..=last_in]
        .iter()
        .filter(|f| f.id == 0x3E8)
        .skip(5)
        .copied()
        .collect()
}

/// Every input was lost at most before the first frame, after the last and at each
/// stall of the test's own feed, and no frame failed its alive counter.
fn assert_inputs_lost_only_at_the_ends(s: &serde_json::Value, stalls: u64) {
    for m in ["WHL_SPD11", "IMU_ACC", "IMU_GYR"] {
        assert!(
            s["messages"][m]["timeouts"].as_u64() <= Some(2 + stalls),
            "{m}: {s}"
        );
        assert_eq!(
            s["messages"][m]["counter_errors"].as_u64(),
            Some(0),
            "{m}: {s}"
        );
    }
}

/// Separate stretches of HOLD_INPUT_LOST in a sequence of statuses: each stall of the
/// test's own feed may cause one, nothing else may.
fn hold_episodes(statuses: &[Status]) -> u64 {
    let mut n = 0;
    let mut prev = None;
    for &st in statuses {
        if st == Status::HoldInputLost && prev != Some(Status::HoldInputLost) {
            n += 1;
        }
        prev = Some(st);
    }
    n
}

/// Set the wall clock `delta_s` away from where it is (root, in the VM).
fn step_wall_clock(delta_s: i64) {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs() as i64;
    let st = Command::new("date")
        .arg("-s")
        .arg(format!("@{}", now + delta_s))
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(st.success(), "date -s failed");
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t8_a_wall_clock_step_changes_neither_the_period_nor_the_estimate() {
    let dir = workdir("clockstep");
    let _bus = Vcan::up();
    let log = drive_log(&dir, "drive.log", |_, _| true);
    let frames = read_frames(&log);
    let span_s = frames.last().unwrap().t_s - frames.first().unwrap().t_s;
    let d = Leveld::start(&dir, "run");
    let capture = Candump::start(dir.join("all.log"), "");
    // One hour forward a third into the drive, and back two thirds into it.
    let stepper = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_secs_f64(span_s / 3.0));
        step_wall_clock(3600);
        std::thread::sleep(Duration::from_secs_f64(span_s / 3.0));
        step_wall_clock(-3600);
    });
    let stalls = play_monotonic(&frames);
    eprintln!("feed stalls: {stalls}");
    stepper.join().unwrap();
    let (all, drops) = capture.stop_with_drops();
    let out_frames = outputs_while_inputs_flow(&all);
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let s = Leveld::final_stats(&text);
    assert_eq!(s["wall_clock_steps"].as_u64(), Some(2), "{s}");
    // A clock step must not add a loss (the statuses below check the same while the
    // frames flow).
    assert_inputs_lost_only_at_the_ends(&s, stalls);
    // candump stamps with the wall clock: split its record at the steps and check
    // the period of each part.
    let mut parts: Vec<Vec<LogFrame>> = vec![Vec::new()];
    for w in out_frames.windows(2) {
        if (w[1].t_s - w[0].t_s).abs() > 100.0 {
            parts.push(Vec::new());
        }
        parts.last_mut().unwrap().push(w[1]);
    }
    assert_eq!(parts.len(), 3, "two steps in the candump record");
    for (i, p) in parts.iter().enumerate() {
        let (t0, t1) = (p.first().unwrap().t_s, p.last().unwrap().t_s);
        let rate = periodic_rate(p, t0 + 1.0, t1 - 1.0);
        assert!(
            (9.0..=11.0).contains(&rate),
            "part {i}: LEVELING at {rate:.2} Hz"
        );
    }
    let out = output_codec();
    check_counter_and_crc(&out, &out_frames, Leveld::queue_full(&text) + drops);
    let statuses: Vec<Status> = out_frames
        .iter()
        .map(|f| status(&decode(&out, f)))
        .collect();
    assert!(
        hold_episodes(&statuses) <= stalls,
        "a wall clock step must not look like input loss: {statuses:?}"
    );
    let last = decode(&out, out_frames.last().unwrap());
    assert_eq!(status(&last), Status::Valid);
    assert!(
        (last.road_to_body_deg - TRUTH_DEG).abs() < 0.2,
        "final {} vs truth {TRUTH_DEG}",
        last.road_to_body_deg
    );
}

#[test]
#[ignore = "needs vcan: run by tools/test-all.sh through tools/vcan-vm.sh"]
fn t9_a_daemon_not_scheduled_for_a_while_finds_its_inputs_waiting_not_lost() {
    let dir = workdir("sigstop");
    let _bus = Vcan::up();
    // The first 16 s of the drive: a standstill, a drive-off and a stop.
    let log = drive_log(&dir, "drive.log", |_, t| t < 16.0);
    let frames = read_frames(&log);
    let d = Leveld::start(&dir, "run");
    let capture = Candump::start(dir.join("all.log"), "");
    // Four times 0.4 s without the CPU, four times the timeouts of every input: the
    // kernel queues the frames meanwhile, stamped as they come.
    let pid = d.pid();
    let stopper = std::thread::spawn(move || {
        for _ in 0..4 {
            std::thread::sleep(Duration::from_secs(3));
            unsafe { libc::kill(pid, libc::SIGSTOP) };
            std::thread::sleep(Duration::from_millis(400));
            unsafe { libc::kill(pid, libc::SIGCONT) };
        }
    });
    let stalls = play_monotonic(&frames);
    eprintln!("feed stalls: {stalls}");
    stopper.join().unwrap();
    let all: Vec<LogFrame> = capture.stop();
    let (code, text) = d.term();
    assert_eq!(code, 0, "{text}");
    let s = Leveld::final_stats(&text);
    assert_inputs_lost_only_at_the_ends(&s, stalls);
    for (m, id) in [("WHL_SPD11", 0x386), ("IMU_ACC", 0x3E0), ("IMU_GYR", 0x3E1)] {
        let sent = frames.iter().filter(|f| f.id == id).count() as u64;
        assert_eq!(
            s["messages"][m]["frames"].as_u64(),
            Some(sent),
            "{m}: every frame read, none lost in the socket: {s}"
        );
    }
    let out = output_codec();
    let statuses: Vec<Status> = outputs_while_inputs_flow(&all)
        .iter()
        .map(|f| status(&decode(&out, f)))
        .collect();
    assert!(statuses.len() > 100, "{} LEVELING frames", statuses.len());
    assert!(
        hold_episodes(&statuses) <= stalls,
        "queued frames must not look like input loss: {statuses:?}"
    );
}
