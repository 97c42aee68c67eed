//! From window geometry to the estimate: eq. 16 per window, the average (eq. 17 or
//! Huber), shifts and load changes applied to it.

use super::average::PitchTerms;
use super::window::{self, Step, WindowSetup};
use super::{Condition, Estimate, Estimator, Event, RejectReason, WindowReport};
use nalgebra::{UnitQuaternion, Vector3};

/// Uncertainty of a load step measured at a standstill, deg: on the realistic drives
/// the settled references on either side mostly agree with the step within a few
/// hundredths (0.1 where the reference before the ramp was taken while the body still
/// rocked), and the gyro's turn over a ramp that ends at drive-off within about 0.1.
const LOAD_STEP_SD_DEG: f64 = 0.05;

/// Largest direction of travel in the IMU's frame a window's lane-roll correction
/// takes, rad (5 deg): an IMU yawed further on its mount is mounted wrong, and a single
/// window's path finds the yaw to a few tenths of a degree.
const MAX_TRAVEL_YAW_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// A run of windows must stand this many standard errors from the estimate to be taken
/// for a shift: its weighted mean against the spread of windows of its weight and the
/// estimate's own standard error. Three windows beyond 0.4 deg on one side also come
/// from noise: single windows on realistic drives are 0.2-0.45 deg rms, and an estimate
/// 0.2 deg off (two standard errors early in a drive) sees that in about one run of
/// three in a hundred, which a drive of 30 windows then takes for a shift.
const SHIFT_Z: f64 = 4.0;

/// Accepted windows in a row beyond `shift_deg` on one side of the estimate.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct ShiftRun {
    side: f64,
    count: usize,
    /// Sum of the windows' weights, and of weight times distance from the estimate, deg.
    weight: f64,
    weighted_dev_deg: f64,
    /// Spread of a window of weight 1 and the estimate's variance where the run began,
    /// deg^2: the run's own windows would widen both and hide a shift behind itself.
    window_var: f64,
    estimate_var: f64,
}

impl Estimator {
    /// Count windows in a row that sit beyond `shift_deg` on the same side of the
    /// estimate; true when `shift_windows` of them (this one included) agree and their
    /// weighted mean stands `SHIFT_Z` standard errors from the estimate.
    pub(super) fn track_shift(&mut self, window_deg: f64, weight: f64) -> bool {
        let (k, thr) = (self.cfg.shift_windows, self.cfg.shift_deg);
        let Some(e) = self.estimate.filter(|_| k >= 2) else {
            self.shift_run = ShiftRun::default();
            return false;
        };
        let d = window_deg - e.road_to_body_deg;
        let r = &mut self.shift_run;
        if d.abs() <= thr {
            *r = ShiftRun::default();
            return false;
        }
        if d.signum() != r.side {
            let estimate_var = e.std_err_deg.powi(2);
            *r = ShiftRun {
                side: d.signum(),
                window_var: estimate_var * e.weight.max(1.0),
                estimate_var,
                ..ShiftRun::default()
            };
        }
        r.count += 1;
        r.weight += weight;
        r.weighted_dev_deg += weight * d;
        if r.count < k || r.weight <= 0.0 {
            return false;
        }
        let mean_dev = r.weighted_dev_deg / r.weight;
        let sd = (r.window_var / r.weight + r.estimate_var).sqrt();
        mean_dev.abs() > SHIFT_Z * sd
    }

    pub(super) fn apply_load_change(
        &mut self,
        delta_rad: f64,
        new_pitch_rad: f64,
        t_s: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        self.baseline_pitch_rad = Some(new_pitch_rad);
        if let Some(st) = self.standstill.as_mut() {
            // The turn since the standstill began is now in the estimate.
            st.begin.shown = Default::default();
            st.begin.closed = true;
        }
        self.shift_run = ShiftRun::default();
        self.avg.restart_shifted(
            delta_rad.to_degrees(),
            LOAD_STEP_SD_DEG,
            self.cfg.load_prior_windows,
        );
        self.refresh_estimate();
        emit(Event::LoadChanged {
            t_s,
            delta_deg: delta_rad.to_degrees(),
            estimate: self.estimate,
        });
    }

    pub(super) fn finish_forward(&mut self, step: Step, t_now: f64, emit: &mut dyn FnMut(Event)) {
        let Step::Done(r) = step else { return };
        let Some(ctx) = self.fwd_ctx.take() else {
            return;
        };
        // A walk of `window_distance_m` from rest ends faster than any wheel sensor's
        // dead zone: one that ends with the wheels still at zero, never having read a
        // speed since it began, covered its distance on drift while the car stood (a
        // standstill begun while the car still crawled, and the stop after it lost).
        let unseen =
            ctx.speed_mismatch.is_none() && !ctx.speed_checked && self.wheels_zero_since.is_some();
        let r = match (r, ctx.speed_mismatch) {
            (Ok(_), Some((imu_mps, wheel_mps))) => {
                Err(RejectReason::SpeedMismatch { imu_mps, wheel_mps })
            }
            (Ok(_), None) if unseen => Err(RejectReason::SpeedMismatch {
                imu_mps: self.fwd.horizontal_speed_mps(),
                wheel_mps: 0.0,
            }),
            (r, _) => r,
        };
        let share = if ctx.reference_settled {
            1.0
        } else {
            self.cfg.short_stop_weight
        };
        self.report_window_weighted(
            r,
            Condition::AccelAfterStop,
            ctx.imu_pitch_rad,
            (t_now, t_now),
            share,
            emit,
        );
    }

    /// How far from its chord the accelerometer's noise alone takes a walk of 1 s, m:
    /// white noise of density `sigma` integrated twice and tied to the chord between
    /// its ends sits `sigma T^1.5 / sqrt(48)` from it at mid-walk (one standard
    /// deviation), `chord_noise_sigmas` of those. 0 before the noise is learnt.
    pub(super) fn noise_chord_m(&self) -> f64 {
        self.walk_acc_noise_per_rthz()
            .filter(|sigma| sigma.is_finite())
            .map_or(0.0, |sigma| {
                self.cfg.chord_noise_sigmas * sigma / 48f64.sqrt()
            })
    }

    /// `reference_q`: see `WindowSetup::reference_q`.
    pub(super) fn window_setup(
        &self,
        q0: UnitQuaternion<f64>,
        reference_q: UnitQuaternion<f64>,
        g: f64,
    ) -> WindowSetup {
        let c = &self.cfg;
        WindowSetup {
            q0,
            reference_q,
            gyro_bias_rps: self.bias_rps.unwrap_or_else(Vector3::zeros),
            acc_bias_mps2: self.acc_bias_mps2(),
            gravity_mps2: g,
            lever_arm_m: self.lever_arm(),
            distance_m: c.window_distance_m,
            check_extra_m: c.chord_check_extra_m,
            max_time_s: c.max_window_time_s,
            max_gap_s: c.max_imu_gap_s,
            max_yaw_rate_rps: c.max_yaw_rate_dps.to_radians(),
            max_lateral_acc_mps2: c.max_lateral_acc_mps2,
            max_chord_deviation_m: c.max_chord_deviation_m,
            noise_chord_m: self.noise_chord_m(),
            velocity_free: c.velocity_free_slope && !self.quiet_accelerometer(),
            velocity_free_max_chord_m: c.velocity_free_max_chord_m,
            short_share: c.short_window_share,
            axle_m: if c.axle_chord && self.quiet_accelerometer() {
                c.wheelbase_m
            } else {
                0.0
            },
        }
    }

    pub(super) fn report_window(
        &mut self,
        r: Result<window::WindowGeometry, RejectReason>,
        condition: Condition,
        imu_pitch_rad: f64,
        t_s: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        self.report_window_weighted(r, condition, imu_pitch_rad, (t_s, t_s), 1.0, emit);
    }

    /// `report_window` for a window worth `weight_share` of a settled one of its length,
    /// reported at `t_s` and measured against the body's pitch at `reference_s`.
    pub(super) fn report_window_weighted(
        &mut self,
        r: Result<window::WindowGeometry, RejectReason>,
        condition: Condition,
        imu_pitch_rad: f64,
        (t_s, reference_s): (f64, f64),
        weight_share: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        match r {
            Ok(mut g) => {
                let mut walk_rad = g.slope_per_bias_x;
                let mut terms = PitchTerms::default();
                if let Some((slope_rad, t)) = self.axle_slope_rad(&g, condition, imu_pitch_rad) {
                    g.slope_rad = slope_rad;
                    walk_rad = g.axle.map_or(walk_rad, |p| p.slope_per_bias_x);
                    if self.cfg.follow_learnt_pitch {
                        terms = t;
                    }
                }
                // The value is the pitch less the slope; the reference's tilt moves both.
                let walk = self.cfg.rebias_by_walk.then(|| -walk_rad.to_degrees());
                // As measured, with the body's pitch on the stop's grade still in it;
                // the average takes that out with the share it fits (`GradeShare`).
                let measured = imu_pitch_rad - g.slope_rad + self.lane_roll_pitch_rad(&g);
                let pull = self.grade_pull_mps2(&g, condition, imu_pitch_rad);
                let r2b = measured - self.avg.grade_pitch_deg(pull).to_radians();
                if let Some((delta, new_pitch)) = self.pending_load.take() {
                    // Keep the suspected load change only if this window agrees with it.
                    let shifted_closer = self.estimate.is_none_or(|e| {
                        let w = r2b.to_degrees();
                        (w - (e.road_to_body_deg + delta.to_degrees())).abs()
                            < (w - e.road_to_body_deg).abs()
                    });
                    if shifted_closer {
                        self.apply_load_change(delta, new_pitch, t_s, emit);
                    }
                }
                // A window known to be less reliable than a settled one neither starts
                // nor breaks a run of windows that show a shift.
                let weight = if self.cfg.weight_windows {
                    let noise = self.window_noise_ratio();
                    let share = if weight_share < 1.0 {
                        short_stop_share(g.duration_s, g.distance_m, weight_share, noise)
                    } else {
                        weight_share
                    };
                    window_weight(g.duration_s, g.distance_m, noise) * share
                } else {
                    1.0
                };
                let shifted = weight_share >= 1.0 && self.track_shift(r2b.to_degrees(), weight);
                let open_pair = self.open_pair.take();
                let paired = condition == Condition::AccelAfterStop
                    && self.cfg.pair_stop_windows
                    && open_pair.is_some_and(|h| {
                        self.avg
                            .merge_newest(h, measured.to_degrees(), weight, pull, walk, terms)
                    });
                if !paired {
                    let h =
                        self.avg
                            .push_on_grade(measured.to_degrees(), weight, pull, walk, terms);
                    if condition == Condition::DecelBeforeStop {
                        self.open_pair = Some(h);
                        self.stop_window = Some(h);
                    }
                }
                self.last_slope_rad = Some(g.slope_rad);
                self.travel_yaw.0 += g
                    .travel_yaw_rad
                    .clamp(-MAX_TRAVEL_YAW_RAD, MAX_TRAVEL_YAW_RAD);
                self.travel_yaw.1 = self.travel_yaw.1.saturating_add(1);
                self.refresh_estimate();
                if shifted {
                    let before = self.estimate.map_or(0.0, |e| e.road_to_body_deg);
                    self.avg.restart_from_newest(self.cfg.shift_windows);
                    self.refresh_estimate();
                    self.shift_run = ShiftRun::default();
                    let after = self.estimate.map_or(before, |e| e.road_to_body_deg);
                    emit(Event::PitchShifted {
                        t_s,
                        delta_deg: after - before,
                        estimate: self.estimate,
                    });
                }
                let window = WindowReport {
                    t_s,
                    reference_s,
                    condition,
                    imu_pitch_deg: imu_pitch_rad.to_degrees(),
                    road_slope_deg: g.slope_rad.to_degrees(),
                    road_to_body_deg: r2b.to_degrees(),
                    distance_m: g.distance_m,
                    duration_s: g.duration_s,
                    start_s: g.start_s,
                    chord_deviation_m: g.chord_deviation_m,
                };
                if let Some(estimate) = self.estimate {
                    emit(Event::WindowAccepted { window, estimate });
                }
            }
            Err(reason) => {
                if condition == Condition::AccelAfterStop {
                    self.open_pair = None;
                }
                emit(Event::WindowRejected {
                    t_s,
                    condition,
                    reason,
                })
            }
        }
    }

    /// What a lane's roll adds to the IMU's x-axis pitch, taken back out, rad (0 unless
    /// the end-of-line calibration gave the IMU's roll on the level floor).
    ///
    /// The window's slope is the path's, but the reference pitch is the elevation of
    /// the IMU's x axis. An IMU yawed on its mount by psi has that axis psi off the
    /// travel, and on a lane that falls to the side by phi it reads psi phi more than
    /// on a level lane: 0.03 deg for 1.2 deg of yaw and a 2.5 % crossfall, the same
    /// sign on every lane of a crowned road. The elevation along the travel, x-axis
    /// pitch plus the travel's yaw times the IMU's roll, does not depend on the lane's
    /// roll; the IMU's own roll on its mount is a constant of it that the floor's roll
    /// takes out. Both rolls are of the raw force, so an accelerometer bias is in both.
    fn lane_roll_pitch_rad(&self, g: &window::WindowGeometry) -> f64 {
        let Some(floor_roll) = self.floor_roll_rad else {
            return 0.0;
        };
        let up_y = g.start_up_y + self.acc_bias_mps2().y / super::STANDARD_GRAVITY_MPS2;
        let roll = up_y.clamp(-1.0, 1.0).asin();
        let yaw = g
            .travel_yaw_rad
            .clamp(-MAX_TRAVEL_YAW_RAD, MAX_TRAVEL_YAW_RAD);
        yaw * (roll - floor_roll)
    }

    /// The slope of the line through the contact points the body stood on at rest,
    /// rad, from the walk one wheelbase out (`window::AxlePoint`); `None` where the
    /// window's own slope stays.
    ///
    /// The body's pitch at rest is the chord between its axles plus the load's pitch.
    /// The window's slope is the road's over a few metres ahead or behind, and the two
    /// differ where the road is not one plane: the unevenness under the axles (about
    /// 0.08 deg rms on ordinary asphalt) and a vertical curve. One wheelbase out, the
    /// rear wheels stand where the front ones stood (the front where the rear stood,
    /// walking back), and their height there is the pitch centre's less the
    /// wheelbase's share behind (ahead of) it times the road's pitch of the body
    /// there: the gyro's turn from rest less the pitch the acceleration gave it, from
    /// the learnt pitch per m/s^2 (braking's walking back from a stop, pulling away's
    /// walking on from one). Until the braking one is learnt (the first braking), none.
    /// With the slope, how the window's value (pitch less slope) moves with the dive
    /// and squat learnt, so that the average reads it with the ones learnt later.
    fn axle_slope_rad(
        &mut self,
        g: &window::WindowGeometry,
        condition: Condition,
        imu_pitch_rad: f64,
    ) -> Option<(f64, PitchTerms)> {
        let p = g.axle?;
        let per_force = self.grade.per_force_rad();
        if !self.cfg.correct_grade_pitch || per_force <= 0.0 {
            return None;
        }
        let squat = self.squat_per_force_rad();
        // The force pitch is linear in the dive and the squat: (per dive, per squat).
        let (share, (per_dive, per_squat)) = match condition {
            Condition::AccelAfterStop => (
                self.cfg.pitch_centre_share,
                self.squat_pitch_terms(p.accel_mps2, g.slope_rad),
            ),
            Condition::DecelBeforeStop => (1.0 - self.cfg.pitch_centre_share, (p.accel_mps2, 0.0)),
        };
        let force_pitch = per_dive * per_force + per_squat * squat;
        let road_turn = (p.pitch_rad - imu_pitch_rad) - force_pitch;
        // The value takes the share of the force pitch out.
        let terms = PitchTerms::new(
            -share * per_dive,
            -share * per_squat,
            per_force.to_degrees(),
            squat.to_degrees(),
        );
        Some((p.slope_rad - share * road_turn, terms))
    }

    /// The pitch pulling away at `accel_mps2` on a road of `slope_rad` gives the body
    /// beyond its pitch held at rest there, as its factors of the dive and of the squat
    /// per m/s^2, m/s^2: the squat's k times the drivetrain's force, which takes over
    /// the grade's pull from the brakes (the share of it the body shows, as the average
    /// fits it), less the dive's k times that pull, the pitch the brakes held at rest.
    fn squat_pitch_terms(&mut self, accel_mps2: f64, slope_rad: f64) -> (f64, f64) {
        let pull = super::STANDARD_GRAVITY_MPS2 * slope_rad.sin();
        let held = self.avg.share() * pull;
        (-held, accel_mps2 + held)
    }

    /// The pull of the window's grade along the road at its stop, g sin(slope), m/s^2
    /// (0 with `correct_grade_pitch` off): the body dives or squats under it as under
    /// braking (`estimator/grade.rs`), by the share of that the average fits. A
    /// deceleration window first teaches the body's dive under braking: its mean pitch
    /// against the reference at rest.
    fn grade_pull_mps2(
        &mut self,
        g: &window::WindowGeometry,
        condition: Condition,
        imu_pitch_rad: f64,
    ) -> f64 {
        if !self.cfg.correct_grade_pitch {
            return 0.0;
        }
        match condition {
            Condition::DecelBeforeStop => {
                let rest = g.rest_centre_pitch_rad.unwrap_or(imu_pitch_rad);
                self.grade.learn(g.mean_accel_mps2, g.mean_pitch_rad - rest);
            }
            // From the pitch held at rest on the grade to the squat under the force.
            Condition::AccelAfterStop if self.cfg.learn_squat => {
                // The dive's factor is minus the pull the brakes held at rest.
                let (per_dive, force) = self.squat_pitch_terms(g.mean_accel_mps2, g.slope_rad);
                let held_pitch_rad = -per_dive * self.grade.per_force_rad();
                self.squat
                    .learn(force, g.mean_pitch_rad - imu_pitch_rad + held_pitch_rad);
            }
            Condition::AccelAfterStop => {}
        }
        self.avg
            .set_pitch_per_force(self.grade.per_force_rad().to_degrees());
        self.avg
            .set_squat_per_force(self.squat_per_force_rad().to_degrees());
        super::STANDARD_GRAVITY_MPS2 * g.slope_rad.sin()
    }

    /// What the accelerometer's y bias, as far as the stops do not know it, leaves in
    /// every window of an IMU yawed on its mount, deg (1 sigma). A window measures along
    /// the travel, which such an IMU sees turned by its yaw psi from its x axis; the
    /// reference it measures from is tilted about x by the unknown part of the y bias,
    /// b / g, and the travel's pitch takes psi b / g of that (1.5 deg of yaw and 0.2
    /// m/s^2: 0.03 deg). The floor's roll carries the bias as the car left the line,
    /// so that the lane roll's correction cannot tell it either. Every window of a drive
    /// shares it, and only stops at different roll (lanes falling either way) teach the
    /// bias, so no number of windows averages it away: it is added to the standard
    /// error, from the mean travel yaw of the windows.
    fn yaw_bias_sd_deg(&self) -> f64 {
        let (sum, n) = self.travel_yaw;
        if n == 0 {
            return 0.0;
        }
        let yaw = (sum / f64::from(n)).abs();
        (yaw * self.acc_bias_sd_mps2()[1] / super::STANDARD_GRAVITY_MPS2).to_degrees()
    }

    pub(super) fn refresh_estimate(&mut self) {
        let accepted = self.avg.accepted();
        let combined = self.avg.combined();
        if let Some(c) = combined {
            self.grade_share = c.grade_share;
        }
        let unseen = self.yaw_bias_sd_deg();
        self.estimate = combined.map(|c| Estimate {
            road_to_body_deg: c.value_deg,
            std_err_deg: c.std_err_deg.hypot(unseen),
            windows: accepted,
            weight: c.weight,
        });
    }
}

/// Error model of one window of duration T over the distance D, deg^2: a part that does
/// not depend on them (the standstill reference, the body's heave and vibration at the
/// window's ends) and one that grows as T^3 / D^2. White accelerometer noise of density
/// n, integrated twice and fitted over the window, gives 0.3 n^2 T^3 / D^2 rad^2 (0.0085
/// deg^2 per s^3/m^2 at 300 ug/sqrt(Hz)); the drift of the accelerometer bias since the
/// reference adds to it. Fitted to the mean square error of 3400 windows of the
/// realistic family at 2 and 3 m (8 seeds, every scenario and load): 0.010 + 0.015 x
/// for x = T^3 / D^2 from 0.6 to 12.
const WINDOW_VAR_FIXED_DEG2: f64 = 0.010;
const WINDOW_VAR_PER_X_DEG2: f64 = 0.015;
/// x = T^3 / D^2 of the window that weighs 1 (2 s over 2.8 m), s^3/m^2. Brisk windows
/// of 3 m are 0.6-1.3.
const WINDOW_REF_X: f64 = 1.0;

/// Accelerometer noise density the error model was fitted at, m/s^2/sqrt(Hz): the
/// realistic family's 300 ug/sqrt(Hz).
const WINDOW_MODEL_NOISE_MPS2_RTHZ: f64 = 300e-6 * super::STANDARD_GRAVITY_MPS2;

/// The model's x = T^3 / D^2 of a window of `duration_s` over `distance_m`, s^3/m^2.
fn window_x(duration_s: f64, distance_m: f64) -> f64 {
    duration_s.max(0.0).powi(3) / distance_m.max(0.1).powi(2)
}

/// Predicted variance of a window of x = T^3 / D^2 from an accelerometer whose noise
/// density is `noise_ratio` times the model's, deg^2: the part that grows with x is
/// the noise's, and goes as its square.
fn window_var_deg2(x: f64, noise_ratio: f64) -> f64 {
    WINDOW_VAR_FIXED_DEG2 + WINDOW_VAR_PER_X_DEG2 * noise_ratio * noise_ratio * x
}

/// Weight of a window of `duration_s` over `distance_m` in the average: its inverse
/// predicted variance relative to that of the reference window, at most 1 (so the
/// weight still counts windows towards a converged status) and at least 0.1, for an
/// accelerometer `noise_ratio` times as noisy as the model's.
pub(super) fn window_weight(duration_s: f64, distance_m: f64, noise_ratio: f64) -> f64 {
    let x = window_x(duration_s, distance_m);
    (window_var_deg2(WINDOW_REF_X, noise_ratio) / window_var_deg2(x, noise_ratio)).clamp(0.1, 1.0)
}

/// Share of its settled weight that a window from a stop too short to settle keeps,
/// given `share_at_model` (`short_stop_weight`) at the model's noise and the walk's
/// noise `noise_ratio` times the model's. The reference of such a stop is read on a
/// swinging body: an error of the body's that a quieter accelerometer does not shrink,
/// kept at the size it has at the model's noise, (1 / share - 1) times the window's own.
pub(super) fn short_stop_share(
    duration_s: f64,
    distance_m: f64,
    share_at_model: f64,
    noise_ratio: f64,
) -> f64 {
    let x = window_x(duration_s, distance_m);
    let own = window_var_deg2(x, noise_ratio);
    let extra = window_var_deg2(x, 1.0) * (1.0 / share_at_model - 1.0);
    own / (own + extra)
}

impl Estimator {
    /// The walk's accelerometer noise learnt at rest over the model's, 1 before it is
    /// learnt (or with `noise_scaled_weights` off).
    fn window_noise_ratio(&self) -> f64 {
        if !self.cfg.noise_scaled_weights {
            return 1.0;
        }
        self.walk_acc_noise_per_rthz()
            .filter(|n| n.is_finite() && *n >= 0.0)
            .map_or(1.0, |n| n / WINDOW_MODEL_NOISE_MPS2_RTHZ)
    }
}

/// The first wheel speed after a drive-off may differ from the speed the forward window
/// integrated by this much, m/s, plus `SPEED_CHECK_SHARE` of it (tyre radius).
const SPEED_CHECK_TOL_MPS: f64 = 0.12;
const SPEED_CHECK_SHARE: f64 = 0.05;

impl Estimator {
    /// Compare the first wheel reading above the dead zone after a drive-off with the
    /// speed the forward window has integrated since the walk began at rest. When they
    /// disagree, the stop's deceleration window goes too: it stands on the same
    /// reference, and a car that only rolled through under the wheels' dead zone (the
    /// IMU finds no drive-off where the car never stopped, and integrates nothing by
    /// the time the wheels read 0.5 m/s) gave it a velocity that was not zero.
    pub(super) fn check_forward_speed(
        &mut self,
        t_s: f64,
        wheel_mps: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        if !self.fwd.is_active() {
            return;
        }
        let imu_mps = self.fwd.horizontal_speed_mps();
        // The wheel speed may be up to `max_wheel_speed_age_s` old. The walk began at
        // rest and pulls away at a steady rate: back then the IMU was that share of its
        // walk slower.
        let walked_s = self.fwd.elapsed_s();
        let aged_mps = if walked_s > 0.0 {
            imu_mps * (1.0 - self.cfg.max_wheel_speed_age_s / walked_s).max(0.0)
        } else {
            imu_mps
        };
        let Some(ctx) = self.fwd_ctx.as_mut().filter(|c| !c.speed_checked) else {
            return;
        };
        ctx.speed_checked = true;
        let off = (aged_mps - wheel_mps).max(wheel_mps - imu_mps).max(0.0);
        if off <= SPEED_CHECK_TOL_MPS + SPEED_CHECK_SHARE * wheel_mps {
            return;
        }
        ctx.speed_mismatch = Some((imu_mps, wheel_mps));
        // The car was moving where its "rest" taught the stop filter: what it taught goes.
        if let Some(before) = ctx.stop_bias_before.take() {
            self.stop_bias = before;
            self.follow_stop_bias(t_s, emit);
        }
        if let Some(value_deg) = self
            .stop_window
            .take()
            .and_then(|h| self.avg.withdraw_newest(h))
        {
            self.open_pair = None;
            self.shift_run = ShiftRun::default();
            self.refresh_estimate();
            emit(Event::WindowWithdrawn {
                t_s,
                road_to_body_deg: value_deg,
                imu_mps,
                wheel_mps,
                estimate: self.estimate,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Condition, Estimator, EstimatorConfig, Event};
    use super::window::WindowGeometry;
    use super::{short_stop_share, window_weight};

    /// Report one accepted window of `value_deg` that took `duration_s` over 3 m;
    /// returns the shift it caused, deg.
    fn window(est: &mut Estimator, t_s: f64, value_deg: f64, duration_s: f64) -> Option<f64> {
        let g = WindowGeometry {
            slope_rad: 0.0,
            slope_per_bias_x: 0.0,
            distance_m: 3.0,
            duration_s,
            start_s: t_s,
            chord_deviation_m: 0.0,
            max_yaw_rate_rps: 0.0,
            max_lateral_acc_mps2: 0.0,
            mean_pitch_rad: 0.0,
            mean_accel_mps2: 0.0,
            travel_yaw_rad: 0.0,
            start_up_y: 0.0,
            rest_centre_pitch_rad: None,
            axle: None,
        };
        let mut shift = None;
        let imu = value_deg.to_radians();
        est.report_window(Ok(g), Condition::DecelBeforeStop, imu, t_s, &mut |e| {
            if let Event::PitchShifted { delta_deg, .. } = e {
                shift = Some(delta_deg);
            }
        });
        shift
    }

    /// An estimate of 1.0 deg from 16 brisk windows that spread 0.25 deg.
    fn settled() -> Estimator {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        for i in 0..16 {
            let noise = [0.2, -0.2, 0.3, -0.3][i % 4];
            assert_eq!(window(&mut est, i as f64, 1.0 + noise, 2.0), None);
        }
        let e = est.estimate.unwrap();
        assert!((e.road_to_body_deg - 1.0).abs() < 0.02, "{e:?}");
        est
    }

    #[test]
    fn a_run_of_windows_is_a_shift_only_when_its_mean_stands_clear_of_the_noise() {
        // Three brisk windows 0.5 deg low: each beyond `shift_deg`, but with windows
        // that spread 0.25 deg their mean is only 3 standard errors off, which noise does.
        let mut est = settled();
        for t in 20..23 {
            assert_eq!(window(&mut est, t as f64, 0.5, 2.0), None);
        }
        // Three gentle drive-offs 0.7 deg high weigh a quarter each: still noise.
        let mut est = settled();
        for t in 20..23 {
            assert_eq!(window(&mut est, t as f64, 1.7, 4.0), None);
        }
        // The pitch moved by 1 deg unseen: the third brisk window shows it.
        let mut est = settled();
        assert_eq!(window(&mut est, 20.0, 2.05, 2.0), None);
        assert_eq!(window(&mut est, 21.0, 1.95, 2.0), None);
        let shift = window(&mut est, 22.0, 2.0, 2.0).expect("a shift");
        let e = est.estimate.unwrap();
        assert!(
            shift > 0.8 && (e.road_to_body_deg - 2.0).abs() < 0.05,
            "{shift} {e:?}"
        );
    }

    #[test]
    fn long_windows_weigh_less_and_the_weight_is_bounded() {
        // 2 s over 2.8 m is the reference window; a brisk 3 m window weighs as much.
        assert!((window_weight(2.0, 8f64.sqrt(), 1.0) - 1.0).abs() < 1e-12);
        assert_eq!(window_weight(1.8, 3.0, 1.0), 1.0);
        // A gentle drive-off (0.4 m/s^2 over 3 m) counts a quarter of that.
        let gentle = window_weight((2.0 * 3.0 / 0.4f64).sqrt(), 3.0, 1.0);
        assert!(gentle > 0.2 && gentle < 0.3, "{gentle}");
        // The same duration over a longer distance is the better window.
        assert!(window_weight(3.0, 2.0, 1.0) < window_weight(3.0, 3.0, 1.0));
        assert_eq!(window_weight(0.1, 3.0, 1.0), 1.0);
        assert_eq!(window_weight(20.0, 3.0, 1.0), 0.1);
    }

    #[test]
    fn a_quiet_accelerometer_weighs_slow_windows_alike_but_short_stops_less() {
        let gentle = (2.0 * 3.0 / 0.4f64).sqrt();
        // At a tenth of the model's noise a gentle window is nearly as good as a brisk one.
        assert!(window_weight(gentle, 3.0, 0.1) > 0.9);
        assert!(window_weight(gentle, 3.0, 1.0) < 0.3);
        for t in [1.8, gentle] {
            // At the model's noise: the configured share.
            assert!((short_stop_share(t, 3.0, 0.28, 1.0) - 0.28).abs() < 1e-12);
            // A tenth of the noise: the walk's own error is small, the reference's is not.
            let quiet = short_stop_share(t, 3.0, 0.28, 0.1);
            assert!(quiet > 0.02 && quiet < 0.2, "{t} {quiet}");
            // Three times the noise: the walk's error hides the reference's.
            let noisy = short_stop_share(t, 3.0, 0.28, 3.0);
            assert!(noisy > 0.6 && noisy < 1.0, "{t} {noisy}");
        }
        assert_eq!(short_stop_share(2.0, 3.0, 1.0, 0.1), 1.0);
    }
}
