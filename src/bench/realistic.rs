//! The `realistic` scenario family: drives with the physics that real cars and other
//! vehicle models show and that the estimator must not be fooled by. Every effect is an
//! option of the `[realistic]` table of a scenario file; each is on by default there.
//! README ("Realistic drives") and docs/accuracy.md (section 3) state how each was sized.

use super::suite::DriveSpec;
use crate::sim::noise::Gauss;
use crate::sim::scenario::{Road, Scenario, Sensors, Shock, SpeedProfile, Vehicle};
use serde::{Deserialize, Serialize};

/// Effects of a realistic drive. Ranges are [min, max], drawn per drive or per stop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealisticSpec {
    /// Share of drive-offs that pull away gently, and their acceleration, m/s^2.
    pub gentle_start_share: f64,
    pub gentle_accel_mps2: [f64; 2],
    /// Share of stops that never reach rest: the car slows to this speed, then goes, m/s.
    pub rolling_stop_share: f64,
    pub rolling_min_mps: [f64; 2],
    /// Share of stops that last only `short_hold_s`, s.
    pub short_stop_share: f64,
    pub short_hold_s: [f64; 2],
    /// Share of stops with a creep (the brake released and applied again) in the middle,
    /// and the creep's peak speed, m/s; it moves the car well under a window.
    pub creep_share: f64,
    pub creep_peak_mps: [f64; 2],
    /// Share of full stops at which the driver eases off the brake: the last
    /// `soft_stop_s` before rest are braked at only `soft_stop_mps2` (most drivers do
    /// this to spare the passengers the jerk of the stop; a car with one-pedal driving
    /// always does). The car then comes to rest from a walking pace, below the wheels'
    /// dead zone, with little force left to end and little swing after it.
    pub soft_stop_share: f64,
    pub soft_stop_mps2: [f64; 2],
    pub soft_stop_s: [f64; 2],
    /// Share of stops with a door or boarding shock; amplitude (deg), frequency (Hz) and
    /// decay time constant (s) of the body-pitch oscillation.
    pub door_shock_share: f64,
    pub door_shock_deg: [f64; 2],
    pub door_shock_hz: [f64; 2],
    pub door_shock_decay_s: f64,
    /// Share of stops with a gap in the IMU frames, and its length, s.
    pub imu_gap_share: f64,
    pub imu_gap_s: [f64; 2],
    /// A load change starts this long into its stop and ramps over `load_ramp_s`, s.
    pub load_change_delay_s: [f64; 2],
    pub load_ramp_s: f64,
    /// Share of load-change stops that last only `load_stop_short_hold_s` (the ramp ends
    /// near drive-off), s.
    pub load_stop_short_share: f64,
    pub load_stop_short_hold_s: [f64; 2],
    /// Grade changes: vertical curves of this length per percent of change, m, between
    /// stretches of constant grade `grade_stretch_m` long; stops fall anywhere on them.
    pub vertical_curve_m_per_pct: f64,
    pub grade_stretch_m: [f64; 2],
    /// Turns that start at the stop line begin this far past it, m; the steering ramps
    /// in over `curve_ramp_m`, m.
    pub turn_offset_m: [f64; 2],
    pub curve_ramp_m: f64,
    /// Vehicle: body pitch mode (Hz, damping ratio, deg per m/s^2), the IMU's lever arm
    /// (m) and mounting (max |roll|, |pitch|, |yaw|, deg), structural vibration.
    pub pitch_freq_hz: [f64; 2],
    pub pitch_damping: [f64; 2],
    pub pitch_per_accel_deg: [f64; 2],
    /// Squat per m/s^2 of forward force as a share of the dive per m/s^2 of braking
    /// (see `Vehicle::squat_share`).
    pub squat_share: [f64; 2],
    /// The body also pitches with gravity's share along a grade (see
    /// `Vehicle::pitch_from_grade`).
    pub pitch_from_grade: bool,
    /// A load change moves the body through its pitch mode (see
    /// `Vehicle::load_through_suspension`).
    pub load_through_suspension: bool,
    pub lever_arm_m: [f64; 3],
    pub imu_mount_max_deg: [f64; 3],
    pub accel_ramp_s: f64,
    pub vibration_mps2: f64,
    pub vibration_long_share: f64,
    /// Engine vibration at the IMU, at rest and in motion: vertical rms (m/s^2, 0 for
    /// an electric car) and frequency (Hz).
    pub idle_vibration_mps2: f64,
    pub idle_vibration_hz: f64,
    /// Road unevenness (ISO 8608 displacement PSD at 0.1 cycle/m, 1e-6 m^3), and the
    /// body's heave mode that follows it (Hz, damping ratio).
    pub road_roughness_1e6_m3: f64,
    /// Cross slope of the lane, percent, positive falling to the right (the right lane of
    /// a crowned road, 1.5-2.5 % on most; 0, flat, by default).
    pub cross_slope_pct: f64,
    /// Distance between the axles, m (the estimator is configured for 2.7 unless told).
    pub wheelbase_m: f64,
    pub heave_freq_hz: [f64; 2],
    pub heave_damping: [f64; 2],
    /// Body heave per m/s^2 of longitudinal force, mm (see `Vehicle::heave_per_accel_mm`).
    pub heave_per_accel_mm: [f64; 2],
    /// Sensors: largest |bias| per axis (accelerometer m/s^2, gyro deg/s).
    pub acc_bias_max_mps2: f64,
    pub gyro_bias_max_dps: f64,
}

impl Default for RealisticSpec {
    fn default() -> Self {
        Self {
            gentle_start_share: 0.4,
            gentle_accel_mps2: [0.3, 0.6],
            rolling_stop_share: 0.15,
            rolling_min_mps: [0.05, 0.3],
            short_stop_share: 0.15,
            short_hold_s: [1.0, 2.0],
            creep_share: 0.0,
            creep_peak_mps: [0.05, 0.3],
            soft_stop_share: 0.0,
            soft_stop_mps2: [0.2, 0.5],
            soft_stop_s: [0.6, 1.2],
            door_shock_share: 0.33,
            door_shock_deg: [0.1, 0.2],
            door_shock_hz: [5.0, 8.0],
            door_shock_decay_s: 0.1,
            imu_gap_share: 0.2,
            imu_gap_s: [0.1, 0.2],
            load_change_delay_s: [1.0, 3.0],
            load_ramp_s: 3.0,
            load_stop_short_share: 0.5,
            load_stop_short_hold_s: [4.0, 8.0],
            vertical_curve_m_per_pct: 8.0,
            grade_stretch_m: [30.0, 150.0],
            turn_offset_m: [0.3, 1.0],
            curve_ramp_m: 1.0,
            pitch_freq_hz: [1.2, 1.4],
            pitch_damping: [0.2, 0.4],
            pitch_per_accel_deg: [0.15, 0.3],
            squat_share: [1.0, 1.0],
            pitch_from_grade: true,
            load_through_suspension: false,
            lever_arm_m: [2.1, 0.65, 0.4],
            imu_mount_max_deg: [0.8, 1.0, 1.5],
            accel_ramp_s: 0.5,
            vibration_mps2: 0.35,
            vibration_long_share: 0.3,
            idle_vibration_mps2: 0.0,
            idle_vibration_hz: 25.0,
            road_roughness_1e6_m3: 64.0,
            cross_slope_pct: 0.0,
            wheelbase_m: 2.7,
            heave_freq_hz: [1.1, 1.3],
            heave_damping: [0.25, 0.4],
            heave_per_accel_mm: [0.0, 0.0],
            acc_bias_max_mps2: 0.3,
            gyro_bias_max_dps: 1.0,
        }
    }
}

impl RealisticSpec {
    /// Reject settings the ride model cannot run; the error names the key and its range.
    pub fn check(&self) -> anyhow::Result<()> {
        let r = self.road_roughness_1e6_m3;
        if !(r.is_finite() && r >= 0.0) {
            let hint = crate::sim::roughness::PSD_HINT;
            anyhow::bail!("realistic.road_roughness_1e6_m3 = {r}: {hint}");
        }
        use crate::sim::scenario::in_range;
        in_range(
            "realistic.idle_vibration_mps2",
            self.idle_vibration_mps2,
            0.0,
            5.0,
            "give 0-5 m/s^2 (0 for an electric car; an idling engine shakes a body by about 0.05-0.3)",
        )?;
        in_range(
            "realistic.cross_slope_pct",
            self.cross_slope_pct,
            -10.0,
            10.0,
            "give -10..10 % (a crowned road's lanes fall 1.5-2.5 % to the side)",
        )?;
        in_range(
            "realistic.soft_stop_share",
            self.soft_stop_share,
            0.0,
            1.0,
            "give a share of the full stops, 0-1",
        )?;
        in_range(
            "realistic.wheelbase_m",
            self.wheelbase_m,
            1.5,
            5.0,
            "give 1.5-5 m (a passenger car's axles are 2.4-3.1 m apart)",
        )?;
        in_range(
            "realistic.idle_vibration_hz",
            self.idle_vibration_hz,
            5.0,
            100.0,
            "give 5-100 Hz (a four-cylinder engine idling at 750 rpm fires at 25 Hz)",
        )?;
        let range = |key: &str, [lo, hi]: [f64; 2], min: f64, max: f64, hint: &str| {
            if lo.is_finite() && hi.is_finite() && min < lo && lo <= hi && hi <= max {
                Ok(())
            } else {
                Err(anyhow::anyhow!("realistic.{key} = [{lo}, {hi}]: {hint}"))
            }
        };
        range(
            "soft_stop_mps2",
            self.soft_stop_mps2,
            0.0,
            3.0,
            "give [min, max] above 0 m/s^2; a driver easing off the brake ends at 0.2-0.5",
        )?;
        range(
            "soft_stop_s",
            self.soft_stop_s,
            0.0,
            5.0,
            "give [min, max] above 0 s; a driver eases off over the last 0.5-1.5 s",
        )?;
        range(
            "heave_freq_hz",
            self.heave_freq_hz,
            0.0,
            20.0,
            "give [min, max] above 0 Hz; a car body heaves at 1-1.5 Hz",
        )?;
        let [lo, hi] = self.squat_share;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= 2.0) {
            anyhow::bail!(
                "realistic.squat_share = [{lo}, {hi}]: give [min, max] within 0..2; a car \
                 squats by about 0.5-1.5 of what it dives per m/s^2"
            );
        }
        let [lo, hi] = self.heave_per_accel_mm;
        if !(lo.is_finite() && hi.is_finite() && -20.0 <= lo && lo <= hi && hi <= 20.0) {
            anyhow::bail!(
                "realistic.heave_per_accel_mm = [{lo}, {hi}]: give [min, max] within -20..20 mm \
                 per m/s^2; a car body rises or sinks by 0-3 mm per m/s^2 as it pitches"
            );
        }
        range(
            "heave_damping",
            self.heave_damping,
            0.0,
            2.0,
            "give [min, max] damping ratios above 0; a car's are 0.2-0.4",
        )
    }
}

/// What a stop is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopKind {
    Full,
    Rolling,
}

/// Where and when the stops of a realistic drive are, for the benchmark's per-stop checks.
#[derive(Debug, Clone, Default)]
pub struct StopPlan {
    /// (time the stop begins s, time it ends s, kind, drive-off acceleration m/s^2).
    pub stops: Vec<(f64, f64, StopKind, f64)>,
    /// (stop index, time the load ramp ends s).
    pub load_change: Option<(usize, f64)>,
}

fn pick(g: &mut Gauss, r: [f64; 2]) -> f64 {
    r[0] + (r[1] - r[0]) * g.uniform()
}

/// Build one load case of a realistic drive.
pub fn build(spec: &DriveSpec, r: &RealisticSpec, load_idx: usize) -> (Scenario, StopPlan) {
    let mut g = Gauss::new(spec.seed);
    let mut gs = Gauss::new(spec.seed ^ 0x0073_6f66_7473);
    let sym = |g: &mut Gauss, m: f64| (2.0 * g.uniform() - 1.0) * m;
    let mut speed = SpeedProfile::default();
    let mut plan = StopPlan::default();
    let mut shocks = Vec::new();
    let mut gaps = Vec::new();
    let mut t = 0.0;
    let mut s = 0.0;
    let mut stop_s = vec![0.0];
    let load_stop = spec.load_change_at_stop.filter(|_| load_idx > 0);
    let leg_m = spec
        .distance_km
        .map(|km| km * 1000.0 / spec.stops.max(1) as f64);
    // Each stop's kind and, for a rolling stop, the lowest speed it reaches (m/s).
    let kinds: Vec<(StopKind, f64)> = (0..=spec.stops)
        .map(|k| {
            let rolling = g.uniform() < r.rolling_stop_share;
            let v_min = pick(&mut g, r.rolling_min_mps);
            // The drive ends at rest: the last stop is a full one.
            if k > 0 && k < spec.stops && rolling && load_stop != Some(k) {
                (StopKind::Rolling, v_min)
            } else {
                (StopKind::Full, 0.0)
            }
        })
        .collect();
    for k in 0..=spec.stops {
        let (kind, v_min) = kinds[k];
        // People board while the car is held: the stop of a load change lasts at least
        // as long as its short kind (`load_stop_short_hold_s`), and the brake is not
        // released in it (no creep). The draws are made all the same, so the other
        // stops of the drive stay as they were.
        let short = k > 0 && g.uniform() < r.short_stop_share;
        let mut hold = if short && load_stop != Some(k) {
            pick(&mut g, r.short_hold_s)
        } else {
            pick(&mut g, spec.hold_s)
        };
        // Everyone is seated before the car pulls away: the stop lasts until the ramp
        // of its load change, starting `load_change_delay_s` into it, has ended.
        let mut load_delay = 0.0;
        if load_stop == Some(k) {
            hold = if g.uniform() < r.load_stop_short_share {
                pick(&mut g, r.load_stop_short_hold_s)
            } else {
                hold.max(r.load_stop_short_hold_s[0])
            };
            load_delay = pick(&mut g, r.load_change_delay_s);
            hold = hold.max(load_delay + r.load_ramp_s);
        }
        let gentle = g.uniform() < r.gentle_start_share;
        let accel = if gentle {
            pick(&mut g, r.gentle_accel_mps2)
        } else {
            pick(&mut g, spec.accel_mps2)
        };
        let t_stop = t;
        if kind == StopKind::Full {
            let creep = k > 0 && g.uniform() < r.creep_share;
            if creep && hold > 4.0 && load_stop != Some(k) {
                // Brake released, the car creeps, brake applied again.
                let peak = pick(&mut g, r.creep_peak_mps);
                let a = 0.5;
                let h1 = 0.4 * hold;
                let h2 = (hold - h1 - 2.0 * peak / a).max(1.0);
                speed = speed
                    .hold(h1)
                    .accel(a, peak / a)
                    .accel(-a, peak / a)
                    .hold(h2);
                s += peak * peak / a;
                hold = h1 + 2.0 * peak / a + h2;
            } else {
                speed = speed.hold(hold);
            }
            if g.uniform() < r.door_shock_share && hold > 1.5 {
                shocks.push(Shock {
                    t_s: t + pick(&mut g, [0.5, hold - 0.5]),
                    amplitude_deg: pick(&mut g, r.door_shock_deg),
                    freq_hz: pick(&mut g, r.door_shock_hz),
                    decay_s: r.door_shock_decay_s,
                });
            }
            if g.uniform() < r.imu_gap_share && hold > 1.0 {
                gaps.push((
                    t + pick(&mut g, [0.3, hold - 0.4]),
                    pick(&mut g, r.imu_gap_s),
                ));
            }
            if load_stop == Some(k) {
                let t0 = t + load_delay;
                plan.load_change = Some((plan.stops.len(), t0 + r.load_ramp_s));
            }
            t += hold;
        }
        plan.stops.push((t_stop, t, kind, accel));
        stop_s.push(s);
        if k == spec.stops {
            speed = speed.hold(8.0);
            break;
        }
        // Drive off (from rest or from the rolling speed), cruise, brake to the next stop.
        let v_top = pick(&mut g, spec.top_kmh) / 3.6;
        let brake = pick(&mut g, spec.brake_mps2);
        let ta = (v_top - v_min) / accel;
        speed = speed.accel(accel, ta);
        let accel_m = (v_top * v_top - v_min * v_min) / (2.0 * accel);
        let v_end = kinds[k + 1].1;
        // An eased stop: braked at `brake` down to the speed the gentle end starts
        // from. Drawn apart, so that the drives without it stay as they were.
        let ease = (kinds[k + 1].0 == StopKind::Full && gs.uniform() < r.soft_stop_share)
            .then(|| {
                let a = pick(&mut gs, r.soft_stop_mps2).min(brake);
                (a, pick(&mut gs, r.soft_stop_s))
            })
            .filter(|(a, te)| a * te < v_top);
        let (v_eased, ease_m) = ease.map_or((v_end, 0.0), |(a, te)| (a * te, 0.5 * a * te * te));
        let brake_m = (v_top * v_top - v_eased * v_eased) / (2.0 * brake) + ease_m;
        let cruise_m = leg_m
            .map_or(v_top * 5.0, |l| l - accel_m - brake_m)
            .max(20.0);
        speed = speed.hold(cruise_m / v_top);
        let tb = (v_top - v_eased) / brake;
        speed = speed.accel(-brake, tb);
        let te = match ease {
            Some((a, te)) => {
                speed = speed.accel(-a, te);
                te
            }
            None => 0.0,
        };
        s += accel_m + cruise_m + brake_m;
        t += ta + cruise_m / v_top + tb + te;
    }

    let road = hilly_road(spec, r, &mut g, s + 100.0);
    let mut road = road;
    road.curve_ramp_m = r.curve_ramp_m;
    // Drawn apart from the rest, so that the other draws of a seed stay as they were;
    // both loads of a drive ride the same road.
    let mut gr = Gauss::new(spec.seed ^ 0x0068_6561_7665);
    road.roughness = crate::sim::roughness::Roughness {
        psd_1e6_m3: r.road_roughness_1e6_m3,
        seed: spec.seed,
    };
    super::suite::add_bumps(&mut road, &stop_s[1..], spec.bump_share, &mut g);
    for &x in stop_s.iter().skip(1) {
        if g.uniform() < spec.turn_share {
            let start = if g.uniform() < spec.turn_at_line_share {
                x + pick(&mut g, r.turn_offset_m)
            } else {
                x + 12.0
            };
            let dir = if g.uniform() < 0.5 { 1.0 } else { -1.0 };
            road.curves.push((
                start,
                start + 15.0 * std::f64::consts::FRAC_PI_2,
                dir / 15.0,
            ));
        }
    }
    let base_load = spec.loads[0].pitch_deg;
    let (load0, changes) = match (load_idx, plan.load_change) {
        (0, _) => (base_load, Vec::new()),
        (li, Some((_, t_end))) => (
            base_load,
            vec![(
                t_end - r.load_ramp_s,
                spec.loads[li].pitch_deg,
                r.load_ramp_s,
            )],
        ),
        (li, None) => (spec.loads[li].pitch_deg, Vec::new()),
    };
    let vehicle = Vehicle {
        lever_arm_m: r.lever_arm_m,
        pitch_per_accel_deg: pick(&mut g, r.pitch_per_accel_deg),
        pitch_from_grade: r.pitch_from_grade,
        load_through_suspension: r.load_through_suspension,
        pitch_freq_hz: pick(&mut g, r.pitch_freq_hz),
        pitch_damping: pick(&mut g, r.pitch_damping),
        heave_freq_hz: pick(&mut gr, r.heave_freq_hz),
        heave_damping: pick(&mut gr, r.heave_damping),
        // Drawn only when it varies, so that the drives without it stay as they were.
        squat_share: if r.squat_share[0] == r.squat_share[1] {
            r.squat_share[0]
        } else {
            pick(&mut gr, r.squat_share)
        },
        heave_per_accel_mm: if r.heave_per_accel_mm[0] == r.heave_per_accel_mm[1] {
            r.heave_per_accel_mm[0]
        } else {
            pick(&mut gr, r.heave_per_accel_mm)
        },
        rough_road_mps2: r.vibration_mps2,
        rough_road_long_share: r.vibration_long_share,
        idle_vibration_mps2: r.idle_vibration_mps2,
        idle_vibration_hz: r.idle_vibration_hz,
        imu_mount_deg: [
            sym(&mut g, r.imu_mount_max_deg[0]),
            sym(&mut g, r.imu_mount_max_deg[1]),
            sym(&mut g, r.imu_mount_max_deg[2]),
        ],
        accel_ramp_s: r.accel_ramp_s,
        wheelbase_m: r.wheelbase_m,
        ..Vehicle::default()
    };
    let base = spec.sensors.clone().unwrap_or_default();
    let sensors = Sensors {
        acc_bias_mps2: [0; 3].map(|_| sym(&mut g, r.acc_bias_max_mps2)),
        gyro_bias_dps: [0; 3].map(|_| sym(&mut g, r.gyro_bias_max_dps)),
        ..base
    };
    let sc = Scenario {
        speed,
        road,
        load_pitch_deg: load0,
        load_changes: changes,
        vehicle,
        sensors,
        shocks,
        imu_gaps: gaps,
        seed: spec.seed.wrapping_mul(31).wrapping_add(load_idx as u64),
    };
    (sc, plan)
}

/// A road of constant-grade stretches joined by vertical curves (the grade angle changes
/// linearly with distance, `vertical_curve_m_per_pct` per percent).
fn hilly_road(spec: &DriveSpec, r: &RealisticSpec, g: &mut Gauss, length_m: f64) -> Road {
    let deg = |pct: f64| (pct / 100.0).atan().to_degrees();
    let mut knots = Vec::new();
    let mut s = -50.0;
    let mut pct = (2.0 * g.uniform() - 1.0) * spec.grade_max_pct;
    knots.push((s, deg(pct)));
    while s < length_m {
        s += pick(g, r.grade_stretch_m);
        knots.push((s, deg(pct)));
        let next = (2.0 * g.uniform() - 1.0) * spec.grade_max_pct;
        s += (next - pct).abs() * r.vertical_curve_m_per_pct;
        pct = next;
        knots.push((s, deg(pct)));
    }
    Road {
        grade_deg: knots,
        curves: Vec::new(),
        curve_ramp_m: 0.0,
        roughness: Default::default(),
        cross_slope_pct: r.cross_slope_pct,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::simulate;

    #[test]
    fn the_stop_of_a_load_change_is_held_long_enough_to_board_and_never_creeps() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenarios/realistic/stop-and-go.toml"
        ))
        .unwrap();
        let mut spec = DriveSpec::parse(&text).unwrap();
        spec.stops = 6;
        spec.load_change_at_stop = Some(3);
        // Every other stop is short or creeps: the load stop must be neither.
        let r = RealisticSpec {
            short_stop_share: 1.0,
            creep_share: 1.0,
            rolling_stop_share: 0.0,
            ..RealisticSpec::default()
        };
        for seed in 1..=8 {
            spec.seed = seed;
            let (sc, plan) = build(&spec, &r, 1);
            let (k, t_ramp_end) = plan.load_change.expect("5P drives change the load");
            let (t_stop, t_go, ..) = plan.stops[k];
            assert!(
                t_go - t_stop >= r.load_stop_short_hold_s[0],
                "seed {seed}: {t_stop} {t_go}"
            );
            assert!(t_ramp_end - r.load_ramp_s >= t_stop + 0.5, "seed {seed}");
            assert!(
                t_ramp_end <= t_go,
                "seed {seed}: boarding after the drive-off"
            );
            let drive = simulate(&sc);
            // The driver's acceleration ramps in and out over `accel_ramp_s` about the
            // plan's times; a creep would reach 0.05-0.3 m/s in between.
            let ramp = sc.vehicle.accel_ramp_s;
            let moving = drive
                .truth
                .iter()
                .filter(|x| x.t_s > t_stop + ramp && x.t_s < t_go - ramp)
                .any(|x| x.v_mps > 0.01);
            assert!(!moving, "seed {seed}: the car moved during its load stop");
            // The other stops still are short ones (1-2 s held).
            let short = plan.stops[1..]
                .iter()
                .enumerate()
                .filter(|&(i, _)| i + 1 != k)
                .all(|(_, s)| s.1 - s.0 <= r.short_hold_s[1] + 1e-9);
            assert!(short, "seed {seed}: {:?}", plan.stops);
        }
    }

    /// An eased stop ends at the plan's time and place, braked at the gentle rate over
    /// its last part, and the car stands still through the hold.
    #[test]
    fn an_eased_stop_comes_to_rest_from_a_walking_pace_where_planned() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenarios/realistic/urban.toml"
        ))
        .unwrap();
        let mut spec = DriveSpec::parse(&text).unwrap();
        spec.stops = 4;
        let r = RealisticSpec {
            soft_stop_share: 1.0,
            rolling_stop_share: 0.0,
            ..RealisticSpec::default()
        };
        let hard = RealisticSpec {
            rolling_stop_share: 0.0,
            ..RealisticSpec::default()
        };
        for seed in 1..=4 {
            spec.seed = seed;
            let (sc, plan) = build(&spec, &r, 0);
            let (hard_sc, hard_plan) = build(&spec, &hard, 0);
            let drive = simulate(&sc);
            let hard_drive = simulate(&hard_sc);
            for (i, &(t_stop, t_go, ..)) in plan.stops.iter().enumerate().skip(1) {
                // Half a second before rest the car still moves, slower than the
                // wheels' dead zone, and brakes at no more than the gentle rate.
                let before = drive.truth_at(t_stop - 0.5);
                assert!(
                    before.v_mps > 0.5 * 0.5 * r.soft_stop_mps2[0]
                        && before.v_mps < 0.5 * r.soft_stop_mps2[1] + 0.02,
                    "seed {seed} stop {i}: {} m/s half a second before rest",
                    before.v_mps
                );
                let held = drive
                    .truth
                    .iter()
                    .filter(|x| x.t_s > t_stop + 0.05 && x.t_s < t_go - 0.3);
                assert!(held.clone().all(|x| x.v_mps < 1e-3), "seed {seed} stop {i}");
                // The same drive without the easing stops where this one does, later (the
                // ramp into the gentle end moves each stop by 1-2 cm).
                let hard_stop = hard_plan.stops[i].0;
                assert!(t_stop > hard_stop, "seed {seed} stop {i}");
                let (at, hard_at) = (
                    drive.truth_at(t_stop).s_m,
                    hard_drive.truth_at(hard_stop).s_m,
                );
                assert!(
                    (at - hard_at).abs() < 0.025 * i as f64,
                    "seed {seed} stop {i}: {at} m, {hard_at} m"
                );
            }
        }
    }

    /// The simulator against a real car: KITTI raw's OXTS RT3003 (100 Hz) shows a
    /// vertical acceleration std of 0.20 / 0.34 / 0.40 m/s^2 at 0.5-3 / 3-6 / 8-20 m/s.
    /// The urban drives' road unevenness, suspension and structural vibration come
    /// within 0.7-1.4 of each; a smooth road is at 0.3-0.5 of the two slow bands.
    #[test]
    fn vertical_vibration_by_speed_is_close_to_a_real_cars() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenarios/realistic/urban.toml"
        ))
        .unwrap();
        let mut spec = DriveSpec::parse(&text).unwrap();
        let real = [0.20, 0.34, 0.40];
        let std_by_band = |spec: &mut DriveSpec, r: &RealisticSpec| {
            let mut bands = [(0.0, 0usize); 3];
            for seed in [101, 102] {
                spec.seed = seed;
                let d = simulate(&build(spec, r, 0).0);
                // The vertical force about its mean over the surrounding 4 s.
                let f: Vec<f64> = d.imu.iter().map(|x| x.acc()[2]).collect();
                for i in 200..f.len() - 200 {
                    let v = d.truth_at(d.imu[i].t_s).v_mps;
                    let b = match v {
                        v if (0.5..3.0).contains(&v) => 0,
                        v if (3.0..6.0).contains(&v) => 1,
                        v if (8.0..20.0).contains(&v) => 2,
                        _ => continue,
                    };
                    let mean = f[i - 200..i + 200].iter().sum::<f64>() / 400.0;
                    bands[b].0 += (f[i] - mean).powi(2);
                    bands[b].1 += 1;
                }
            }
            bands.map(|(ss, n)| (ss / n.max(1) as f64).sqrt())
        };
        let r = spec.realistic.clone().unwrap_or_default();
        let rough = std_by_band(&mut spec, &r);
        eprintln!("vertical std by band, m/s^2: {rough:.3?} (a real car: {real:?})");
        for (b, (sim, real)) in rough.iter().zip(real).enumerate() {
            let ratio = sim / real;
            assert!(
                (0.7..=1.4).contains(&ratio),
                "band {b}: {sim:.3} m/s^2 against a real car's {real}"
            );
        }
        let smooth = RealisticSpec {
            road_roughness_1e6_m3: 0.0,
            ..r
        };
        let smooth = std_by_band(&mut spec, &smooth);
        eprintln!("on a smooth road: {smooth:.3?}");
        assert!(
            smooth[0] < 0.5 * real[0] && smooth[1] < 0.5 * real[1],
            "{smooth:?}"
        );
    }
}
