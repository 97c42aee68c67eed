//! Per-stop checks of a realistic drive: what leveld made of each gentle drive-off,
//! rolling stop and load change, against the drive's stop plan.

use super::realistic::StopKind;
use super::suite::Case;
use crate::estimator::{Condition, Estimator, EstimatorConfig, Event, RejectReason};
use crate::sim::{Input, simulate};
use serde::Serialize;

/// Drive-offs at or below this are gentle, m/s^2.
pub const GENTLE_MPS2: f64 = 0.6;
/// A window belongs to a drive-off when it completes this soon after it, s.
const DRIVE_OFF_WINDOW_S: f64 = 15.0;
/// A drive-off counts when the car covers a window's distance after it, m.
const DRIVE_OFF_MIN_M: f64 = 2.0;
/// A load change counts as applied when the estimate's step over its stop (from the
/// stop's start to just before drive-off) is within this of the true step, deg, and
/// still is `LOAD_KEPT_S` after drive-off (a step shown at rest and then dropped does
/// not count).
pub const LOAD_APPLIED_TOL_DEG: f64 = 0.1;
/// See `LOAD_APPLIED_TOL_DEG`, s.
pub const LOAD_KEPT_S: f64 = 1.0;
/// Load changes at least this large are checked, deg.
pub const LOAD_CHECKED_DEG: f64 = 0.5;

/// What happened at the stops of one drive.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StopChecks {
    pub scenario: String,
    pub load: String,
    pub seed: u64,
    /// Full stops left with a gentle drive-off, and how many gave an accepted window.
    pub gentle_drive_offs: usize,
    pub gentle_accepted: usize,
    /// Why the other gentle drive-offs gave no window.
    pub gentle_lost: LostDriveOffs,
    /// Rolling stops, and how many gave an accepted window or a load change.
    pub rolling_stops: usize,
    pub rolling_with_output: usize,
    /// Load changes of at least `LOAD_CHECKED_DEG`, and how many were applied within
    /// `LOAD_APPLIED_TOL_DEG` before the drive-off of their stop.
    pub load_changes: usize,
    pub load_applied: usize,
    /// The estimate was converged before the 6th stop began (`None`: fewer stops).
    pub valid_within_5_stops: Option<bool>,
    /// Signed errors of the accepted windows, deg.
    #[serde(skip)]
    pub window_errors: Vec<f64>,
}

/// Why gentle drive-offs gave no accepted window: the first rejection of an acceleration
/// window after the drive-off, or no standstill at that stop at all.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct LostDriveOffs {
    /// No standstill began at the stop (too short, or the body never quiet).
    pub no_standstill: usize,
    /// The reference at the drive-off was not good enough (`NotStill`).
    pub not_still: usize,
    pub slope_not_constant: usize,
    pub turning: usize,
    pub speed_mismatch: usize,
    /// Too short, too slow, an IMU gap, or no window event at all.
    pub other: usize,
}

impl LostDriveOffs {
    fn count(&mut self, reason: Option<RejectReason>, had_standstill: bool) {
        let slot = match reason {
            _ if !had_standstill => &mut self.no_standstill,
            Some(RejectReason::NotStill) => &mut self.not_still,
            Some(RejectReason::SlopeNotConstant { .. }) => &mut self.slope_not_constant,
            Some(RejectReason::Turning { .. }) => &mut self.turning,
            Some(RejectReason::SpeedMismatch { .. }) => &mut self.speed_mismatch,
            _ => &mut self.other,
        };
        *slot += 1;
    }

    /// Drive-offs counted, whatever the reason.
    pub fn total(&self) -> usize {
        self.no_standstill
            + self.not_still
            + self.slope_not_constant
            + self.turning
            + self.speed_mismatch
            + self.other
    }

    fn add(&mut self, o: &Self) {
        self.no_standstill += o.no_standstill;
        self.not_still += o.not_still;
        self.slope_not_constant += o.slope_not_constant;
        self.turning += o.turning;
        self.speed_mismatch += o.speed_mismatch;
        self.other += o.other;
    }
}

/// Run leveld (default configuration) over a realistic case and check its stops.
/// `valid` says whether an estimate counts as converged (the benchmark's rule).
pub fn check(case: &Case, valid: &dyn Fn(&crate::estimator::Estimate) -> bool) -> StopChecks {
    let mut out = StopChecks {
        scenario: case.scenario_name.clone(),
        load: case.load.clone(),
        seed: case.seed,
        ..StopChecks::default()
    };
    let Some(plan) = &case.plan else {
        return out;
    };
    let drive = simulate(&case.scenario);
    let mut est = Estimator::new(EstimatorConfig::default()).expect("default config is valid");
    est.set_floor_roll_deg(Some(crate::sim::floor_roll_deg(&case.scenario)));
    let mut events: Vec<Event> = Vec::new();
    // Estimate just before each stop's drive-off, and the first converged time.
    let mut before_go: Vec<Option<f64>> = vec![None; plan.stops.len()];
    let mut at_stop: Vec<Option<f64>> = vec![None; plan.stops.len()];
    let mut after_go: Vec<Option<f64>> = vec![None; plan.stops.len()];
    let mut next_kept = 0;
    let mut next_start = 0;
    let mut valid_at: Option<f64> = None;
    let mut next_stop = 0;
    for input in drive.merged() {
        let t = match input {
            Input::Imu(s) => {
                est.push_imu(s, &mut |e| events.push(e));
                s.t_s
            }
            Input::Wheels(w) => {
                est.push_wheels(w, &mut |e| events.push(e));
                w.t_s
            }
        };
        while next_start < plan.stops.len() && t >= plan.stops[next_start].0 {
            at_stop[next_start] = est.estimate().map(|e| e.road_to_body_deg);
            next_start += 1;
        }
        while next_stop < plan.stops.len() && t >= plan.stops[next_stop].1 {
            before_go[next_stop] = est.estimate().map(|e| e.road_to_body_deg);
            next_stop += 1;
        }
        while next_kept < plan.stops.len() && t >= plan.stops[next_kept].1 + LOAD_KEPT_S {
            after_go[next_kept] = est.estimate().map(|e| e.road_to_body_deg);
            next_kept += 1;
        }
        if valid_at.is_none() && est.estimate().is_some_and(|e| valid(&e)) {
            valid_at = Some(t);
        }
    }
    let t_end = drive.truth.last().map_or(0.0, |x| x.t_s);
    est.finish(t_end, &mut |e| events.push(e));

    let mut last_value = None;
    for e in &events {
        match e {
            Event::WindowAccepted { window, .. } => {
                let truth = drive.truth_at(window.reference_s).load_pitch_deg;
                out.window_errors.push(window.road_to_body_deg - truth);
                last_value = Some(window.road_to_body_deg);
            }
            // Taken back out of the estimate: no longer an accepted window.
            Event::WindowWithdrawn {
                road_to_body_deg, ..
            } if last_value == Some(*road_to_body_deg) => {
                out.window_errors.pop();
                last_value = None;
            }
            _ => {}
        }
    }
    for (k, &(t_stop, t_go, kind, accel)) in plan.stops.iter().enumerate() {
        match kind {
            // The plan's last stop may end the drive: its drive-off never comes.
            StopKind::Full
                if k > 0
                    && accel <= GENTLE_MPS2
                    && drive.truth_at(t_go + DRIVE_OFF_WINDOW_S).s_m - drive.truth_at(t_go).s_m
                        >= DRIVE_OFF_MIN_M =>
            {
                out.gentle_drive_offs += 1;
                let accepted = events.iter().any(|e| {
                    matches!(e, Event::WindowAccepted { window, .. }
                        if window.condition == Condition::AccelAfterStop
                            && window.t_s > t_go
                            && window.t_s < t_go + DRIVE_OFF_WINDOW_S)
                });
                out.gentle_accepted += usize::from(accepted);
                if !accepted {
                    let had_standstill = events.iter().any(|e| {
                        matches!(e, Event::StandstillStarted { t_s, .. }
                            if *t_s >= t_stop - 1.0 && *t_s < t_go + 1.0)
                    });
                    let reason = events.iter().find_map(|e| match e {
                        Event::WindowRejected {
                            t_s,
                            condition: Condition::AccelAfterStop,
                            reason,
                        } if *t_s > t_go - 1.0 && *t_s < t_go + DRIVE_OFF_WINDOW_S => Some(*reason),
                        _ => None,
                    });
                    out.gentle_lost.count(reason, had_standstill);
                }
            }
            StopKind::Rolling => {
                out.rolling_stops += 1;
                // Anything produced around the moment of lowest speed comes from it: the
                // stops before and after are more than a cruise away.
                let near = |t: f64| t > t_stop - 2.0 && t < t_stop + 8.0;
                let output = events.iter().any(|e| match e {
                    Event::WindowAccepted { window, .. } => near(window.t_s),
                    Event::LoadChanged { t_s, .. } => near(*t_s),
                    _ => false,
                });
                out.rolling_with_output += usize::from(output);
            }
            _ => {}
        }
        if let Some((stop_idx, _)) = plan.load_change
            && stop_idx == k
        {
            let before = drive.truth_at(t_stop).load_pitch_deg;
            let after = drive.truth_at(t_go).load_pitch_deg;
            if (after - before).abs() >= LOAD_CHECKED_DEG {
                out.load_changes += 1;
                let within = |e1: Option<f64>| match (at_stop[k], e1) {
                    (Some(e0), Some(e1)) => {
                        ((e1 - e0) - (after - before)).abs() <= LOAD_APPLIED_TOL_DEG
                    }
                    _ => false,
                };
                let applied = within(before_go[k]) && within(after_go[k]);
                out.load_applied += usize::from(applied);
            }
        }
    }
    out.valid_within_5_stops = plan
        .stops
        .get(6)
        .map(|s| valid_at.is_some_and(|t| t <= s.0));
    out
}

/// Checks of several drives of one scenario and load case, summed.
#[derive(Debug, Clone, Serialize)]
pub struct StopSummary {
    pub scenario: String,
    pub load: String,
    pub drives: usize,
    pub gentle_drive_offs: usize,
    pub gentle_accepted: usize,
    pub gentle_lost: LostDriveOffs,
    pub rolling_stops: usize,
    pub rolling_with_output: usize,
    pub load_changes: usize,
    pub load_applied: usize,
    /// Drives converged within 5 stops, of the drives with at least 6 stops.
    pub valid_within_5: usize,
    pub valid_checked: usize,
    /// Mean signed error of all accepted windows, deg.
    pub mean_window_err_deg: f64,
    pub windows: usize,
}

pub fn summarize(checks: &[StopChecks]) -> Vec<StopSummary> {
    let mut keys: Vec<(&str, &str)> = Vec::new();
    for c in checks {
        if !keys.contains(&(c.scenario.as_str(), c.load.as_str())) {
            keys.push((c.scenario.as_str(), c.load.as_str()));
        }
    }
    keys.into_iter()
        .map(|(s, l)| {
            let g: Vec<&StopChecks> = checks
                .iter()
                .filter(|c| c.scenario == s && c.load == l)
                .collect();
            let errs: Vec<f64> = g
                .iter()
                .flat_map(|c| c.window_errors.iter().copied())
                .collect();
            StopSummary {
                scenario: s.to_string(),
                load: l.to_string(),
                drives: g.len(),
                gentle_drive_offs: g.iter().map(|c| c.gentle_drive_offs).sum(),
                gentle_accepted: g.iter().map(|c| c.gentle_accepted).sum(),
                gentle_lost: g.iter().fold(LostDriveOffs::default(), |mut a, c| {
                    a.add(&c.gentle_lost);
                    a
                }),
                rolling_stops: g.iter().map(|c| c.rolling_stops).sum(),
                rolling_with_output: g.iter().map(|c| c.rolling_with_output).sum(),
                load_changes: g.iter().map(|c| c.load_changes).sum(),
                load_applied: g.iter().map(|c| c.load_applied).sum(),
                valid_within_5: g
                    .iter()
                    .filter(|c| c.valid_within_5_stops == Some(true))
                    .count(),
                valid_checked: g
                    .iter()
                    .filter(|c| c.valid_within_5_stops.is_some())
                    .count(),
                mean_window_err_deg: if errs.is_empty() {
                    f64::NAN
                } else {
                    errs.iter().sum::<f64>() / errs.len() as f64
                },
                windows: errs.len(),
            }
        })
        .collect()
}
