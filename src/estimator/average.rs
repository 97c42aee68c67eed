//! Combination of accepted windows into one road-to-body pitch (eq. 17 and a robust variant).

use super::config::Averaging;
use serde::{Deserialize, Serialize};

/// Fixed-capacity set of weighted window values for the current load, deg.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Averager {
    mode: Averaging,
    capacity: usize,
    sigma_prior_deg: f64,
    /// (value deg, weight) oldest first; a load-change prior has weight > 1. A window's
    /// value is its road-to-body pitch as measured, the grade's pitch still in it.
    entries: Vec<(f64, f64)>,
    /// Per entry, the grade's pull along the road at its stop, g sin(slope), m/s^2 (0
    /// for a prior). Missing entries (a state written before it was kept) read as 0.
    #[serde(default)]
    pulls_mps2: Vec<f64>,
    /// The body's pitch per m/s^2 of braking, deg (`estimator/grade.rs`): an entry's
    /// pitch from its grade is `grade_share` times this times its pull.
    #[serde(default)]
    per_force_deg: f64,
    /// Per entry, the accelerometer's x bias its windows were measured with, m/s^2
    /// (`None`: none to follow, as for an end-of-line seed or a state written before it
    /// was kept). See [`Averager::set_acc_bias_x`].
    #[serde(default)]
    bias_x_mps2: Vec<Option<f64>>,
    /// The x bias the stops know now, m/s^2: every entry is read as if measured with it.
    #[serde(default)]
    acc_bias_x_mps2: f64,
    /// Per entry, how far its value moves per m/s^2 of x bias, from its windows' own
    /// walks, deg (`None`: `per_force_deg`, the body's mean dive per m/s^2, stands in).
    #[serde(default)]
    walk_per_bias_deg: Vec<Option<f64>>,
    /// Per entry, how its value moves with the body's dive and squat per m/s^2 (see
    /// [`PitchTerms`]); a state written before they were kept has none.
    #[serde(default)]
    pitch_terms: Vec<PitchTerms>,
    /// The body's squat per m/s^2 pulling away learnt so far, deg (see
    /// [`Averager::set_squat_per_force`]).
    #[serde(default)]
    squat_per_force_deg: f64,
    /// What the windows of earlier loads (or a saved state) showed of the grade share,
    /// the prior of the current fit (see `GradeShare`).
    #[serde(default)]
    share_prior: GradeShare,
    /// Windows accepted since the last load change (or reset).
    accepted: u64,
    /// Spread of single windows measured before the last load changes: sum of squares
    /// (deg^2) and degrees of freedom. The windows are gone, but what they showed of the
    /// window noise still holds.
    #[serde(default)]
    carried_ss: f64,
    #[serde(default)]
    carried_dof: f64,
    #[serde(skip)]
    scratch: Vec<f64>,
    /// Counts every change of `entries`: a [`PairHandle`] stays good while it holds.
    #[serde(skip)]
    changes: u64,
    /// Bit i is set when the i-th newest entry is a pair of windows (see `merge_newest`).
    #[serde(skip)]
    pair_bits: u64,
}

/// The newest entry as it was when a window was pushed; see [`Averager::merge_newest`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PairHandle(u64);

/// How a window's value depends on the body's pitch per m/s^2 the estimator had
/// learnt when it measured it: `per_dive_mps2` deg of value per deg per m/s^2 of dive,
/// `per_squat_mps2` per deg per m/s^2 of squat, and `taken_deg` what the two gave with
/// the dive and squat of then. A window whose walk one wheelbase out takes the pitch the
/// force gave the body there out of its slope (`estimator/fusion.rs`, `axle_slope_rad`)
/// took it with the suspension as learnt so far; read with the one learnt now, the
/// windows of a drive's first stops count as if measured with it. The terms of a pair
/// of windows are their weighted mean, like their values. All 0: nothing to follow.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PitchTerms {
    pub per_dive_mps2: f64,
    pub per_squat_mps2: f64,
    pub taken_deg: f64,
}

impl PitchTerms {
    /// Terms of `per_dive_mps2` and `per_squat_mps2` taken with a dive and squat of
    /// `dive_deg` and `squat_deg` per m/s^2.
    pub fn new(per_dive_mps2: f64, per_squat_mps2: f64, dive_deg: f64, squat_deg: f64) -> Self {
        Self {
            per_dive_mps2,
            per_squat_mps2,
            taken_deg: per_dive_mps2 * dive_deg + per_squat_mps2 * squat_deg,
        }
    }

    /// A window's force is at most a few m/s^2 and its pitch per m/s^2 below a degree;
    /// terms beyond that (a damaged state file) are not a window's.
    fn plausible(&self) -> bool {
        self.per_dive_mps2.abs() <= MAX_PITCH_TERM_MPS2
            && self.per_squat_mps2.abs() <= MAX_PITCH_TERM_MPS2
            && self.taken_deg.abs() <= MAX_PITCH_TERM_MPS2 * 2.0
    }

    fn mean(&self, w0: f64, other: &Self, w1: f64) -> Self {
        let w = w0 + w1;
        Self {
            per_dive_mps2: (self.per_dive_mps2 * w0 + other.per_dive_mps2 * w1) / w,
            per_squat_mps2: (self.per_squat_mps2 * w0 + other.per_squat_mps2 * w1) / w,
            taken_deg: (self.taken_deg * w0 + other.taken_deg * w1) / w,
        }
    }

    /// What they give with the dive and squat learnt now, less what they gave then, deg.
    fn moved_deg(&self, dive_deg: f64, squat_deg: f64) -> f64 {
        let d = self.per_dive_mps2 * dive_deg + self.per_squat_mps2 * squat_deg - self.taken_deg;
        if d.is_finite() { d } else { 0.0 }
    }
}

/// See [`Averager::fit`].
struct Fit {
    value_deg: f64,
    weight: f64,
    ss: f64,
    dof: f64,
    /// Spread of a window of weight 1, pooled (`pooled_sigma_deg`), deg.
    sigma_deg: f64,
    share: f64,
    /// 1 / variance of `share`: what the windows and the prior say of it once the
    /// value is free.
    share_precision: f64,
    /// Weight of the value once the share is free: the entries' weight less what the
    /// share's own uncertainty takes from it.
    value_precision: f64,
}

/// The share of the braking pitch (`estimator/grade.rs`) that a body standing on a
/// grade shows: 1 where the brakes hold the car on the grade the way they hold it
/// under braking, 0 for a body that stands on every grade as on level ground. The
/// windows tell the two apart where stops come at different grades: the estimate is
/// the load's pitch plus the share times each window's braking pitch for its grade,
/// fitted to both at once.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GradeShare {
    pub mean: f64,
    /// 1 / variance. Windows of weight w whose grade pitch at share 1 is z deg tell
    /// w z^2 / sigma^2 of it, sigma the spread of a window of weight 1. 0 (a state
    /// written before it was kept) stands for the prior.
    pub precision: f64,
}

/// The physics' prior: a car at rest on a grade is held by its brakes, so a body
/// dives or squats there as under braking (share 1) ...
pub(super) const SHARE_PRIOR: f64 = 1.0;
/// ... and anti-dive geometry, a parking brake on one axle or a vehicle model without
/// it can make it anything from 0 up: one standard deviation, half of it. On hilly
/// drives (stops at grades to 15 %) 16-26 windows of 300 ug/sqrt(Hz) take the share
/// from 1 to 0.0-0.5 for a body that does not pitch on grades. (A standard deviation
/// of 1 measured no better there and worse on bodies that do.)
const SHARE_PRIOR_SD: f64 = 0.5;
/// The share is kept to 0..1.5: a body does not squat against the force on it, and
/// more than 1.5 times its braking pitch is a fit to noise.
const SHARE_RANGE: (f64, f64) = (0.0, 1.5);
/// A saved entry's bias beyond this is not an accelerometer's (5 m/s^2: half a g).
const MAX_BIAS_X_MPS2: f64 = 5.0;
/// A window's pitch term beyond this is not a window's, m/s^2 (see [`PitchTerms`]).
const MAX_PITCH_TERM_MPS2: f64 = 20.0;
/// A window's walk answer to the x bias beyond this is not a window's (10 deg per
/// m/s^2: a 3 deg turn from rest in a walk at 0.3 m/s^2).
const MAX_WALK_PER_BIAS_DEG: f64 = 10.0;

impl Default for GradeShare {
    fn default() -> Self {
        Self {
            mean: SHARE_PRIOR,
            precision: 0.0,
        }
    }
}

/// Combined estimate with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Combined {
    pub value_deg: f64,
    /// Standard error of the combined value, deg.
    pub std_err_deg: f64,
    /// Effective number of windows behind the value (a load-change prior counts as its weight).
    pub weight: f64,
    /// The fitted share of its braking pitch the body shows on a grade (see [`GradeShare`]).
    pub grade_share: f64,
}

impl Averager {
    pub fn new(mode: Averaging, capacity: usize, sigma_prior_deg: f64) -> Self {
        Self {
            mode,
            capacity,
            sigma_prior_deg,
            entries: Vec::with_capacity(capacity),
            pulls_mps2: Vec::with_capacity(capacity),
            per_force_deg: 0.0,
            bias_x_mps2: Vec::with_capacity(capacity),
            acc_bias_x_mps2: 0.0,
            walk_per_bias_deg: Vec::with_capacity(capacity),
            pitch_terms: Vec::with_capacity(capacity),
            squat_per_force_deg: 0.0,
            share_prior: GradeShare::default(),
            accepted: 0,
            carried_ss: 0.0,
            carried_dof: 0.0,
            scratch: Vec::with_capacity(capacity),
            changes: 0,
            pair_bits: 0,
        }
    }

    pub fn accepted(&self) -> u64 {
        self.accepted
    }

    /// Add one window value, deg.
    pub fn push(&mut self, value_deg: f64) {
        self.push_window(value_deg, 1.0);
    }

    /// Add one window value (deg) with a weight relative to a typical window (its
    /// inverse predicted variance against that of a typical window).
    pub fn push_window(&mut self, value_deg: f64, weight: f64) -> PairHandle {
        self.push_on_grade(value_deg, weight, 0.0, None, PitchTerms::default())
    }

    /// `push_window` for a window measured against a reference at rest on a grade that
    /// pulls `pull_mps2` (g sin(slope)) along the road: its value still holds the
    /// body's pitch on that grade, which the fit takes out (see [`GradeShare`]).
    /// `walk_per_bias_deg`: how far the window's value moves per m/s^2 of x bias
    /// through its walk (`None`: as far as the body's mean dive per m/s^2); `terms`:
    /// how it moves with the dive and squat learnt (see [`PitchTerms`]).
    pub fn push_on_grade(
        &mut self,
        value_deg: f64,
        weight: f64,
        pull_mps2: f64,
        walk_per_bias_deg: Option<f64>,
        terms: PitchTerms,
    ) -> PairHandle {
        let b = self.acc_bias_x_mps2;
        self.push_weighted(value_deg, weight, pull_mps2, Some(b), walk_per_bias_deg);
        if let Some(t) = self.pitch_terms.last_mut() {
            *t = terms;
        }
        self.accepted = self.accepted.saturating_add(1);
        PairHandle(self.changes)
    }

    /// The body's braking pitch per m/s^2 learnt so far, deg: sets how much pitch a
    /// grade's pull gives at share 1.
    pub fn set_pitch_per_force(&mut self, per_force_deg: f64) {
        if per_force_deg.is_finite() {
            self.per_force_deg = per_force_deg;
        }
    }

    /// The body's squat per m/s^2 pulling away learnt so far, deg: with the braking
    /// pitch, what every entry's [`PitchTerms`] are read with.
    pub fn set_squat_per_force(&mut self, squat_deg: f64) {
        if squat_deg.is_finite() {
            self.squat_per_force_deg = squat_deg;
        }
    }

    /// The accelerometer's x bias the stops know now, m/s^2. The stops learn it slowly
    /// (from stops at different grades), and a window measured with the bias `b0` known
    /// then is off by what the body's pitch in the window turns of the rest, `b - b0`:
    /// the walk rotates it into the vertical by the body's dive or squat, `k (b - b0)`
    /// deg for `k` what the window's own walk says (the gyro's turn from its reference,
    /// read as its slope reads the path), else the body's mean pitch per m/s^2 of force;
    /// and the reference tilts by
    /// `(b - b0) / g`, which moves the grade's pull by `b - b0` and its pitch by `share k
    /// (b - b0)`. Both are taken out of every entry as the fit reads it, so the windows
    /// from before the bias was known count as if measured with the bias known now.
    pub fn set_acc_bias_x(&mut self, bias_x_mps2: f64) {
        if bias_x_mps2.is_finite() {
            self.acc_bias_x_mps2 = bias_x_mps2;
        }
    }

    /// The pitch the body has at rest on a grade pulling `pull_mps2` beyond its pitch
    /// on level ground, as the current fit has it, deg.
    pub fn grade_pitch_deg(&mut self, pull_mps2: f64) -> f64 {
        self.share() * self.per_force_deg * pull_mps2
    }

    /// The fitted grade share (its prior before any window).
    pub fn share(&mut self) -> f64 {
        self.fit().map_or(self.share_prior.mean, |f| f.share)
    }

    /// Fold a window into the newest entry, if that is still the one `handle` was
    /// given for: the two become one entry, their weighted mean with the sum of their
    /// weights. Windows of one stop share its standstill reference and their errors
    /// partly cancel, so the pair is one measurement, not two independent ones.
    /// Returns false (and changes nothing) when the entry is gone or was followed.
    pub fn merge_newest(
        &mut self,
        handle: PairHandle,
        value_deg: f64,
        weight: f64,
        pull_mps2: f64,
        walk_per_bias_deg: Option<f64>,
        terms: PitchTerms,
    ) -> bool {
        if handle.0 != self.changes {
            return false;
        }
        self.sync_pulls();
        let b_now = self.acc_bias_x_mps2;
        let k = self.per_force_deg;
        let (Some(e), Some(p), Some(b), Some(s), Some(t)) = (
            self.entries.last_mut(),
            self.pulls_mps2.last_mut(),
            self.bias_x_mps2.last_mut(),
            self.walk_per_bias_deg.last_mut(),
            self.pitch_terms.last_mut(),
        ) else {
            return false;
        };
        let w = e.1 + weight;
        *t = t.mean(e.1, &terms, weight);
        *p = (*p * e.1 + pull_mps2 * weight) / w;
        // Both measured with a bias (an entry without one takes the window's).
        let b0 = b.unwrap_or(b_now);
        *b = Some((b0 * e.1 + b_now * weight) / w);
        if s.is_some() || walk_per_bias_deg.is_some() {
            let (s0, s1) = (s.unwrap_or(k), walk_per_bias_deg.unwrap_or(k));
            *s = Some((s0 * e.1 + s1 * weight) / w);
        }
        *e = ((e.0 * e.1 + value_deg * weight) / w, w);
        self.pair_bits |= 1;
        self.accepted = self.accepted.saturating_add(1);
        self.changes = self.changes.wrapping_add(1);
        true
    }

    /// Take out the newest entry, if that is still the window `handle` was given for
    /// (nothing pushed, merged or restarted since). An entry the window pushed out of a
    /// full set stays out. Returns the value taken out, deg.
    pub fn withdraw_newest(&mut self, handle: PairHandle) -> Option<f64> {
        if handle.0 != self.changes {
            return None;
        }
        let last = self.entries.len().checked_sub(1)?;
        self.sync_pulls();
        let (value_deg, _, z) = self.graded(last);
        let grade_deg = self.share() * z;
        self.entries.pop();
        self.pulls_mps2.truncate(self.entries.len());
        self.bias_x_mps2.truncate(self.entries.len());
        self.walk_per_bias_deg.truncate(self.entries.len());
        self.pitch_terms.truncate(self.entries.len());
        self.pair_bits >>= 1;
        self.accepted = self.accepted.saturating_sub(1);
        self.changes = self.changes.wrapping_add(1);
        Some(value_deg - grade_deg)
    }

    /// `bias_x_mps2`: the x bias the value was measured with (`None`: none to follow);
    /// `walk_per_bias_deg`: see [`Averager::push_on_grade`].
    fn push_weighted(
        &mut self,
        value_deg: f64,
        w: f64,
        pull_mps2: f64,
        bias_x_mps2: Option<f64>,
        walk_per_bias_deg: Option<f64>,
    ) {
        self.sync_pulls();
        if self.entries.len() == self.capacity {
            self.entries.remove(0);
            self.pulls_mps2.remove(0);
            self.bias_x_mps2.remove(0);
            self.walk_per_bias_deg.remove(0);
            self.pitch_terms.remove(0);
        }
        self.entries.push((value_deg, w));
        self.pulls_mps2.push(if pull_mps2.is_finite() {
            pull_mps2
        } else {
            0.0
        });
        self.bias_x_mps2.push(bias_x_mps2.filter(|b| b.is_finite()));
        self.walk_per_bias_deg
            .push(walk_per_bias_deg.filter(|s| s.abs() <= MAX_WALK_PER_BIAS_DEG));
        self.pitch_terms.push(PitchTerms::default());
        self.changes = self.changes.wrapping_add(1);
        self.pair_bits <<= 1;
    }

    /// One pull and bias per entry; a state written before they were kept has none
    /// (level, no bias to follow).
    fn sync_pulls(&mut self) {
        self.pulls_mps2.resize(self.entries.len(), 0.0);
        self.bias_x_mps2.resize(self.entries.len(), None);
        self.walk_per_bias_deg.resize(self.entries.len(), None);
        self.pitch_terms
            .resize(self.entries.len(), PitchTerms::default());
    }

    /// The entries' walk answer to the x bias under their weights, deg per m/s^2: about
    /// what a value combined from them moves by (`None` without entries).
    fn mean_walk_per_bias_deg(&self) -> Option<f64> {
        let (mut sw, mut w) = (0.0, 0.0);
        for (i, e) in self.entries.iter().enumerate() {
            let s = self.walk_per_bias(i);
            sw += e.1 * s;
            w += e.1;
        }
        (w > 0.0 && sw.is_finite()).then(|| sw / w)
    }

    /// See `walk_per_bias_deg`.
    fn walk_per_bias(&self, i: usize) -> f64 {
        self.walk_per_bias_deg
            .get(i)
            .copied()
            .flatten()
            .unwrap_or(self.per_force_deg)
    }

    /// Restart from a new load: the previous estimate shifted by `delta_deg` (known to
    /// `delta_sd_deg`) is kept as a prior worth at most `prior_weight` windows, and no
    /// more than its uncertainty allows: its standard error and the step's, against the
    /// spread of a typical window. Older windows are dropped.
    pub fn restart_shifted(&mut self, delta_deg: f64, delta_sd_deg: f64, prior_weight: f64) {
        let fit = self.fit();
        let prior = fit.as_ref().map(Fit::combined);
        let walk = self.mean_walk_per_bias_deg();
        if let Some(f) = fit {
            // The new load stands on the same suspension: what the windows showed of
            // the grade share holds.
            if let Some(share) = f.share_as_prior() {
                self.share_prior = share;
            }
            self.carried_ss += f.ss;
            self.carried_dof += f.dof;
            // The carried spread counts as at most one full average of windows.
            let cap = self.capacity as f64;
            if self.carried_dof > cap {
                self.carried_ss *= cap / self.carried_dof;
                self.carried_dof = cap;
            }
        }
        self.entries.clear();
        self.pulls_mps2.clear();
        self.bias_x_mps2.clear();
        self.walk_per_bias_deg.clear();
        self.pitch_terms.clear();
        self.changes = self.changes.wrapping_add(1);
        self.pair_bits = 0;
        self.accepted = 0;
        if let Some(c) = prior {
            let var = c.std_err_deg.powi(2) + delta_sd_deg.powi(2);
            let w = c
                .weight
                .min(prior_weight)
                .min(self.sigma_prior_deg.powi(2) / var);
            if w > 0.0 {
                // The combined value is on level ground: no grade in it; it was read
                // with the bias known now.
                let b = self.acc_bias_x_mps2;
                self.push_weighted(c.value_deg + delta_deg, w, 0.0, Some(b), walk);
            }
        }
    }

    /// Restart from the newest `k` windows alone (they showed the value moved); each
    /// counts as one window.
    pub fn restart_from_newest(&mut self, k: usize) {
        let (mut keep, mut windows) = (0usize, 0usize);
        while windows < k && keep < self.entries.len() {
            windows += if keep < 64 && self.pair_bits >> keep & 1 == 1 {
                2
            } else {
                1
            };
            keep += 1;
        }
        self.sync_pulls();
        self.entries.drain(..self.entries.len() - keep);
        self.pulls_mps2.drain(..self.pulls_mps2.len() - keep);
        self.bias_x_mps2.drain(..self.bias_x_mps2.len() - keep);
        self.walk_per_bias_deg
            .drain(..self.walk_per_bias_deg.len() - keep);
        self.pitch_terms.drain(..self.pitch_terms.len() - keep);
        self.changes = self.changes.wrapping_add(1);
        for (i, e) in self.entries.iter_mut().rev().enumerate() {
            e.1 = if i < 64 && self.pair_bits >> i & 1 == 1 {
                2.0
            } else {
                1.0
            };
        }
        self.accepted = windows as u64;
    }

    /// Current combined value; `None` before any window.
    pub fn combined(&mut self) -> Option<Combined> {
        self.fit().map(|f| f.combined())
    }

    /// Spread of a window of weight 1 from the sum of squares and degrees of freedom
    /// of the current entries, pooled with those carried over load changes and with a
    /// prior worth two windows, so that a handful of agreeing windows does not claim an
    /// implausibly small error, deg.
    fn pooled_sigma_deg(&self, ss: f64, dof: f64) -> f64 {
        let k0 = 2.0;
        let num = k0 * self.sigma_prior_deg.powi(2) + self.carried_ss + ss;
        (num / (k0 + self.carried_dof + dof)).sqrt()
    }

    /// The grade share's prior precision, 1 / variance (see [`GradeShare`]).
    fn share_prior_precision(&self) -> f64 {
        let p = self.share_prior.precision;
        if p.is_finite() && p > 0.0 {
            p
        } else {
            SHARE_PRIOR_SD.powi(-2)
        }
    }

    /// Each entry as (value deg, weight, its pitch from the grade at share 1, deg), read
    /// with the x bias known now (see [`Averager::set_acc_bias_x`]) and the dive and
    /// squat learnt now (see [`PitchTerms`]).
    fn graded(&self, i: usize) -> (f64, f64, f64) {
        let (v, w) = self.entries[i];
        let pull = self.pulls_mps2.get(i).copied().unwrap_or(0.0);
        let db = self
            .bias_x_mps2
            .get(i)
            .copied()
            .flatten()
            .map(|b| self.acc_bias_x_mps2 - b)
            .filter(|d| d.is_finite())
            .unwrap_or(0.0);
        let pitch = self.pitch_terms.get(i).map_or(0.0, |t| {
            t.moved_deg(self.per_force_deg, self.squat_per_force_deg)
        });
        (
            v + self.walk_per_bias(i) * db + pitch,
            w,
            self.per_force_deg * (pull - db),
        )
    }

    /// The value and grade share that fit the entries under the weights `hw(residual,
    /// weight)` gives (weighted least squares with the share's prior, worth `p0` in
    /// window weights times deg^2), and the normal equations' terms.
    fn solve(&self, value: f64, share: f64, p0: f64, hw: impl Fn(f64, f64) -> f64) -> Solved {
        let m0 = if self.share_prior.mean.is_finite() {
            self.share_prior.mean
        } else {
            SHARE_PRIOR
        };
        let (mut a, mut b, mut c, mut r1, mut r2) = (0.0, 0.0, p0, 0.0, p0 * m0);
        for i in 0..self.entries.len() {
            let (v, w, z) = self.graded(i);
            let u = w * hw(v - value - share * z, w);
            a += u;
            b += u * z;
            c += u * z * z;
            r1 += u * v;
            r2 += u * z * v;
        }
        let det = a * c - b * b;
        let share = if det > 0.0 {
            ((a * r2 - b * r1) / det).clamp(SHARE_RANGE.0, SHARE_RANGE.1)
        } else {
            m0
        };
        Solved {
            value: if a > 0.0 { (r1 - share * b) / a } else { value },
            share,
            a,
            b,
            c,
        }
    }

    /// Value of the current entries and what their residuals show of the spread of a
    /// window of weight 1. Each residual is clipped where the Huber estimate stops
    /// following it (a window it discounts moves the value, and so its error, no
    /// further); dividing by the square of the share of weight it follows turns that
    /// clipped sum into the M-estimate's variance (1.03 of a Gaussian's spread at 1.5
    /// sigma). Both change smoothly as a window crosses the clip. One degree of freedom
    /// per entry: a pair of windows or a load-change prior is one residual. The grade
    /// share is fitted with the value (see [`GradeShare`]); its prior keeps the fit
    /// determined when every window stood on the same grade.
    fn fit(&mut self) -> Option<Fit> {
        if self.entries.is_empty() {
            return None;
        }
        self.sync_pulls();
        // The share's prior is a precision of the share; against the windows it weighs
        // as their spread makes it, so the spread of the fit without it comes first.
        let sigma0 = self.pooled_sigma_deg(0.0, 0.0);
        let first = self.fit_with(self.share_prior_precision() * sigma0 * sigma0);
        let sigma = self.pooled_sigma_deg(first.ss, first.dof);
        let mut f = self.fit_with(self.share_prior_precision() * sigma * sigma);
        f.sigma_deg = self.pooled_sigma_deg(f.ss, f.dof);
        f.share_precision /= f.sigma_deg * f.sigma_deg;
        Some(f)
    }

    fn fit_with(&mut self, p0: f64) -> Fit {
        let wsum: f64 = self.entries.iter().map(|e| e.1).sum();
        let (sol, clip) = match self.mode {
            Averaging::Huber if self.entries.len() >= 3 => self.huber(p0),
            _ => (self.solve(0.0, 0.0, p0, |_, _| 1.0), f64::INFINITY),
        };
        let (mut ss, mut followed_w) = (0.0, 0.0);
        for i in 0..self.entries.len() {
            let (v, w, z) = self.graded(i);
            let r = (v - sol.value - sol.share * z).abs();
            let c = entry_clip(clip, w);
            ss += w * r.min(c).powi(2);
            // The Huber weight: 1 inside the clip, clip / residual beyond, so that the
            // share moves smoothly as a window crosses the clip.
            followed_w += w * if r > c { c / r } else { 1.0 };
        }
        let share = (followed_w / wsum).max(0.5);
        Fit {
            value_deg: sol.value,
            weight: wsum,
            ss: ss / (share * share),
            dof: (self.entries.len() as f64 - 1.0).max(0.0),
            sigma_deg: f64::NAN,
            share: sol.share,
            share_precision: sol.c - sol.b * sol.b / sol.a.max(1e-12),
            value_precision: wsum * (sol.a - sol.b * sol.b / sol.c) / sol.a.max(1e-12),
        }
    }

    /// Weighted Huber M-estimate of the value and grade share, and the residual beyond
    /// which it discounts a window of weight 1. Residuals are measured in each entry's
    /// own spread: a window of weight w is expected to scatter 1/sqrt(w) as far as one
    /// of weight 1, so its clip is that much wider, and the scale is the MAD of the
    /// residuals so normalised. A long, noisy window is then discounted for being far
    /// off by its own standards, not for being noisy, which its weight already says.
    fn huber(&mut self, p0: f64) -> (Solved, f64) {
        let m0 = self.share_prior.mean;
        self.scratch.clear();
        for i in 0..self.entries.len() {
            let (v, _, z) = self.graded(i);
            self.scratch.push(v - m0 * z);
        }
        let med = median(&mut self.scratch);
        self.scratch.clear();
        for i in 0..self.entries.len() {
            let (v, w, z) = self.graded(i);
            self.scratch.push((v - m0 * z - med).abs() * w.sqrt());
        }
        // 1.4826 makes the MAD a standard deviation for normal data; the floor keeps
        // identical windows from producing a zero scale.
        let scale = (1.4826 * median(&mut self.scratch)).max(0.02);
        let c = HUBER_CLIP_SIGMA * scale;
        let hw = |r: f64, w: f64| {
            let ci = entry_clip(c, w);
            if r.abs() <= ci { 1.0 } else { ci / r.abs() }
        };
        let mut sol = self.solve(med, m0, p0, hw);
        for _ in 0..20 {
            let next = self.solve(sol.value, sol.share, p0, hw);
            let done =
                (next.value - sol.value).abs() < 1e-9 && (next.share - sol.share).abs() < 1e-9;
            sol = next;
            if done {
                break;
            }
        }
        (sol, c)
    }
}

impl Fit {
    fn combined(&self) -> Combined {
        Combined {
            value_deg: self.value_deg,
            std_err_deg: self.sigma_deg / self.value_precision.max(1e-9).sqrt(),
            weight: self.weight,
            grade_share: self.share,
        }
    }

    /// What the fit showed of the grade share, as the prior of a later fit (a new
    /// load, a restart), no firmer than `MAX_SHARE_PRIORS` first priors; `None` where
    /// it is not finite or out of range.
    fn share_as_prior(&self) -> Option<GradeShare> {
        ((SHARE_RANGE.0..=SHARE_RANGE.1).contains(&self.share) && self.share_precision.is_finite())
            .then(|| GradeShare {
                mean: self.share,
                precision: self
                    .share_precision
                    .clamp(0.0, MAX_SHARE_PRIORS * SHARE_PRIOR_SD.powi(-2)),
            })
    }
}

/// See [`Averager::solve`].
struct Solved {
    value: f64,
    share: f64,
    a: f64,
    b: f64,
    c: f64,
}

/// A grade share carried over load changes is held at most as firmly as this many of
/// its first priors: a car's suspension does not change, but what a few dozen stops
/// showed of it may be off.
const MAX_SHARE_PRIORS: f64 = 16.0;

/// Huber clip in scale units: 95 % of the mean's efficiency on Gaussian windows.
const HUBER_CLIP_SIGMA: f64 = 1.5;

/// Clip of an entry of weight `w` for the clip `c` of a window of weight 1.
fn entry_clip(c: f64, w: f64) -> f64 {
    c / w.max(1e-6).sqrt()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_unstable_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

impl Averager {
    /// Start from `stored`, an average saved earlier: its value as one entry worth the
    /// weight its uncertainty gave it, the spread its windows showed (so a restart
    /// claims no more certainty than the estimate had), and what it learnt of the
    /// grade: the braking pitch and, as the prior, the grade share it fitted. What is
    /// not finite or out of range is left at the prior. Nothing when `stored` is empty.
    pub fn restore_from(&mut self, stored: &mut Averager) {
        stored.sanitize_learnt();
        let Some(f) = stored.fit() else {
            return;
        };
        let weight = if f.value_precision.is_finite() && f.value_precision > 0.0 {
            f.value_precision.min(f.weight)
        } else {
            f.weight
        };
        // The value was read with the bias the saved average knew: it follows the bias
        // from there. An average saved before entries kept their bias has none (its
        // bias field reads 0, which it was not read with): nothing to follow.
        let followed = stored.bias_x_mps2.iter().any(Option::is_some);
        let walk = stored.mean_walk_per_bias_deg();
        self.restore_prior(f.value_deg, weight, stored.accepted());
        if followed {
            self.acc_bias_x_mps2 = stored.acc_bias_x_mps2;
            if let Some(b) = self.bias_x_mps2.last_mut() {
                *b = Some(stored.acc_bias_x_mps2);
            }
            if let Some(s) = self.walk_per_bias_deg.last_mut() {
                *s = walk;
            }
        }
        let (ss, dof) = (stored.carried_ss + f.ss, stored.carried_dof + f.dof);
        if ss.is_finite() && ss >= 0.0 && dof.is_finite() && dof > 0.0 {
            let cap = (self.capacity as f64).min(dof);
            self.carried_ss = ss * cap / dof;
            self.carried_dof = cap;
        }
        if stored.per_force_deg.is_finite() {
            self.per_force_deg = stored.per_force_deg;
        }
        if stored.squat_per_force_deg.is_finite() {
            self.squat_per_force_deg = stored.squat_per_force_deg;
        }
        if let Some(share) = f.share_as_prior() {
            self.share_prior = share;
        }
    }

    /// Put what a saved average learnt of the grade back to the priors where it is not
    /// finite or out of range (a damaged or edited state file), before it is fitted.
    pub fn sanitize_learnt(&mut self) {
        let p = self.share_prior;
        if !((SHARE_RANGE.0..=SHARE_RANGE.1).contains(&p.mean)
            && p.precision.is_finite()
            && p.precision >= 0.0)
        {
            self.share_prior = GradeShare::default();
        }
        if !self.per_force_deg.is_finite() {
            self.per_force_deg = 0.0;
        }
        if !self.squat_per_force_deg.is_finite() {
            self.squat_per_force_deg = 0.0;
        }
        self.pitch_terms.truncate(self.entries.len());
        for t in &mut self.pitch_terms {
            if !t.plausible() {
                *t = PitchTerms::default();
            }
        }
        // Entries cannot be read against a bias that is not an accelerometer's: they
        // are read as measured, and one with such a bias of its own alike.
        let now_ok = self.acc_bias_x_mps2.abs() <= MAX_BIAS_X_MPS2;
        if !now_ok {
            self.acc_bias_x_mps2 = 0.0;
        }
        self.bias_x_mps2.truncate(self.entries.len());
        for b in &mut self.bias_x_mps2 {
            if !now_ok || b.is_some_and(|x| !(x.abs() <= MAX_BIAS_X_MPS2)) {
                *b = None;
            }
        }
        self.walk_per_bias_deg.truncate(self.entries.len());
        for s in &mut self.walk_per_bias_deg {
            if s.is_some_and(|x| !(x.abs() <= MAX_WALK_PER_BIAS_DEG)) {
                *s = None;
            }
        }
    }

    /// Seed with a restored value worth `weight` windows (`accepted` of them under this load).
    pub fn restore_prior(&mut self, value_deg: f64, weight: f64, accepted: u64) {
        self.entries.clear();
        self.pulls_mps2.clear();
        self.bias_x_mps2.clear();
        self.walk_per_bias_deg.clear();
        self.pitch_terms.clear();
        self.carried_ss = 0.0;
        self.carried_dof = 0.0;
        // A seed (end of line, a restored average) reads the bias its own way: nothing
        // to follow unless the caller says (`restore_from`).
        self.push_weighted(value_deg, weight, 0.0, None, None);
        self.pair_bits = 0;
        self.accepted = accepted;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_mode_is_eq17_running_mean() {
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        let xs = [0.3, 0.5, 0.1, 0.9, -0.2];
        let mut running = 0.0;
        for (m, x) in xs.iter().enumerate() {
            a.push(*x);
            let m = (m + 1) as f64;
            running = ((m - 1.0) * running + x) / m; // eq. 17
            assert!((a.combined().unwrap().value_deg - running).abs() < 1e-12);
        }
    }

    #[test]
    fn a_noisy_window_is_judged_by_its_own_spread() {
        // Five settled windows 0.05 deg apart, and a gentle drive-off worth a tenth of
        // one: expected to scatter sqrt(10) times as far, it sits 0.3 deg off, about one
        // of its own standard deviations. Its weight already discounts it; the Huber
        // estimate follows it no less than the weighted mean does.
        let mut h = Averager::new(Averaging::Huber, 64, 0.2);
        let mut m = Averager::new(Averaging::Mean, 64, 0.2);
        let windows = [
            (-0.1, 1.0),
            (-0.05, 1.0),
            (0.0, 1.0),
            (0.05, 1.0),
            (0.1, 1.0),
        ];
        for (x, w) in windows.into_iter().chain([(0.3, 0.1)]) {
            h.push_window(x, w);
            m.push_window(x, w);
        }
        let (hv, mv) = (
            h.combined().unwrap().value_deg,
            m.combined().unwrap().value_deg,
        );
        assert!((hv - mv).abs() < 1e-9, "huber {hv}, mean {mv}");
        // The same window at full weight is 2 of the others' spreads out, and is
        // discounted.
        let mut h = Averager::new(Averaging::Huber, 64, 0.2);
        for x in [-0.1, -0.05, 0.0, 0.05, 0.1, 0.3] {
            h.push(x);
        }
        let mean = 0.3 / 6.0;
        assert!(h.combined().unwrap().value_deg < mean - 0.005);
    }

    #[test]
    fn huber_resists_an_outlier_that_moves_the_mean() {
        let mut h = Averager::new(Averaging::Huber, 64, 0.2);
        let mut m = Averager::new(Averaging::Mean, 64, 0.2);
        for x in [1.02, 0.98, 1.01, 0.99, 1.00, 1.03, 0.97, 5.0] {
            h.push(x);
            m.push(x);
        }
        let (hv, mv) = (
            h.combined().unwrap().value_deg,
            m.combined().unwrap().value_deg,
        );
        assert!((mv - 1.0).abs() > 0.4, "the mean must be pulled: {mv}");
        assert!((hv - 1.0).abs() < 0.05, "huber {hv}");
    }

    #[test]
    fn std_err_shrinks_with_more_windows() {
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        a.push(0.5);
        let e1 = a.combined().unwrap().std_err_deg;
        for x in [0.45, 0.55, 0.5, 0.52, 0.48, 0.51, 0.49] {
            a.push(x);
        }
        let e8 = a.combined().unwrap().std_err_deg;
        assert!(e8 < e1 / 2.0, "{e1} {e8}");
    }

    #[test]
    fn restart_keeps_shifted_prior_with_capped_weight() {
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        for _ in 0..10 {
            a.push(0.5);
        }
        a.restart_shifted(1.0, 0.05, 4.0);
        let c = a.combined().unwrap();
        assert!((c.value_deg - 1.5).abs() < 1e-12);
        assert_eq!(c.weight, 4.0);
        assert_eq!(a.accepted(), 0);
    }

    #[test]
    fn a_restart_keeps_no_more_certainty_than_the_estimate_had() {
        // Four windows that disagree: the estimate is known to about 0.2 deg only.
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        for x in [0.1, 0.9, -0.3, 0.5] {
            a.push(x);
        }
        let before = a.combined().unwrap();
        assert!(before.std_err_deg > 0.15, "{before:?}");
        a.restart_shifted(1.0, 0.05, 4.0);
        let after = a.combined().unwrap();
        assert!((after.value_deg - before.value_deg - 1.0).abs() < 1e-12);
        assert!(after.weight < 1.0, "{after:?}");
        assert!(after.std_err_deg > 0.15, "{after:?}");
    }

    #[test]
    fn a_load_change_keeps_what_the_windows_showed_of_their_spread() {
        // 20 windows 0.1 deg apart: the spread of a window is known far better than
        // the prior of 0.2 deg says.
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        for k in 0..20 {
            a.push(if k % 2 == 0 { 0.4 } else { 0.6 });
        }
        a.restart_shifted(1.0, 0.0, 4.0);
        let c = a.combined().unwrap();
        assert_eq!(c.weight, 4.0);
        // The prior's spread alone would give 0.2 / sqrt(4) = 0.1.
        let sigma = ((2.0f64 * 0.04 + 20.0 * 0.01) / (2.0 + 19.0)).sqrt();
        assert!((c.std_err_deg - sigma / 2.0).abs() < 1e-9, "{c:?}");
        // A restored state knows nothing of the spread.
        a.restore_prior(1.5, 4.0, 0);
        assert!((a.combined().unwrap().std_err_deg - 0.1).abs() < 1e-9);
    }

    #[test]
    fn a_window_the_huber_estimate_discounts_widens_the_error_only_so_far() {
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        for k in 0..10 {
            a.push(if k % 2 == 0 { 0.45 } else { 0.55 });
        }
        let before = a.combined().unwrap();
        a.push(3.0);
        let after = a.combined().unwrap();
        // Unclipped, its square alone would put the error at about 0.22 deg.
        assert!(after.std_err_deg < 0.05, "{before:?} {after:?}");
        assert!(
            after.std_err_deg > before.std_err_deg,
            "{before:?} {after:?}"
        );
    }

    #[test]
    fn restart_from_newest_keeps_only_them() {
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        for _ in 0..10 {
            a.push(0.2);
        }
        for x in [1.7, 1.8, 1.9] {
            a.push(x);
        }
        a.restart_from_newest(3);
        let c = a.combined().unwrap();
        assert!((c.value_deg - 1.8).abs() < 1e-9, "{}", c.value_deg);
        assert_eq!(c.weight, 3.0);
        assert_eq!(a.accepted(), 3);
    }

    #[test]
    fn a_pair_merges_into_its_own_entry_only() {
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        a.push(1.0);
        let h = a.push_window(0.4, 1.0);
        assert!(a.merge_newest(h, 0.0, 0.25, 0.0, None, PitchTerms::default()));
        let c = a.combined().unwrap();
        assert!((c.weight - 2.25).abs() < 1e-12);
        assert!((c.value_deg - (1.0 + 0.4 + 0.0 * 0.25) / 2.25).abs() < 1e-12);
        assert_eq!(a.accepted(), 3);
        // Used once, and never after another window or a restart.
        assert!(!a.merge_newest(h, 0.0, 1.0, 0.0, None, PitchTerms::default()));
        let h = a.push_window(0.5, 1.0);
        a.push(0.6);
        assert!(!a.merge_newest(h, 0.0, 1.0, 0.0, None, PitchTerms::default()));
        let h = a.push_window(0.5, 1.0);
        a.restart_shifted(0.3, 0.05, 4.0);
        assert!(!a.merge_newest(h, 0.0, 1.0, 0.0, None, PitchTerms::default()));
        assert_eq!(a.accepted(), 0);
    }

    #[test]
    fn a_withdrawn_window_leaves_the_average_as_it_was() {
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        a.push(1.0);
        a.push(1.2);
        let before = a.combined().unwrap();
        let h = a.push_window(3.0, 1.0);
        assert_eq!(a.withdraw_newest(h), Some(3.0));
        assert_eq!(a.combined().unwrap(), before);
        assert_eq!(a.accepted(), 2);
        // Only the window the handle was given for, and only once.
        assert_eq!(a.withdraw_newest(h), None);
        let h = a.push_window(3.0, 1.0);
        a.push(0.9);
        assert_eq!(a.withdraw_newest(h), None);
        let h = a.push_window(3.0, 1.0);
        assert!(a.merge_newest(h, 2.0, 1.0, 0.0, None, PitchTerms::default()));
        assert_eq!(a.withdraw_newest(h), None);
        assert_eq!(a.accepted(), 6);
    }

    /// Windows measured with an x bias that the stops later learnt better are read as
    /// if measured with the new one: k per m/s^2 of it through the walk and as much
    /// again (times the grade share) through the grade's pull; a window measured with
    /// the new bias and a restart's prior, read with it, are not moved again.
    #[test]
    fn entries_measured_with_an_older_bias_follow_the_bias_known_now() {
        let k = 0.25;
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        a.set_pitch_per_force(k);
        for v in [1.0, 1.1, 0.9] {
            a.push_on_grade(v, 1.0, 0.5, None, PitchTerms::default());
        }
        let before = a.combined().unwrap().value_deg;
        let share = a.share();
        a.set_acc_bias_x(0.2);
        let after = a.combined().unwrap().value_deg;
        let expected = k * (1.0 + share) * 0.2;
        assert!(
            (after - before - expected).abs() < 1e-9,
            "{before} -> {after}, expected a shift of {expected}"
        );
        // Measured with the bias known now: taken as it is.
        let h = a.push_on_grade(2.0, 1.0, 0.5, None, PitchTerms::default());
        let share_now = a.share();
        assert!((a.withdraw_newest(h).unwrap() - (2.0 - share_now * k * 0.5)).abs() < 1e-9);
        assert!((a.combined().unwrap().value_deg - after).abs() < 1e-9);
        // A load change keeps the estimate as a prior read with this bias; it follows
        // the next change as the windows it came from would have.
        a.restart_shifted(0.0, 0.0, 3.0);
        let restarted = a.combined().unwrap().value_deg;
        assert!((restarted - after).abs() < 1e-9);
        a.set_acc_bias_x(0.3);
        let moved = a.combined().unwrap().value_deg - restarted;
        assert!(
            (moved - k * (1.0 + a.share()) * 0.1).abs() < 1e-9,
            "{moved}"
        );
        // Nothing to follow for an end-of-line seed.
        a.restore_prior(1.5, 1.0, 0);
        a.set_acc_bias_x(-0.3);
        assert_eq!(a.combined().unwrap().value_deg, 1.5);
    }

    /// An entry that knows its own walk's answer to the x bias follows by that, not by
    /// the body's mean dive; a pair by the mean of its two, a load change's prior by
    /// the mean of the entries it came from; the grade's part stays k share.
    #[test]
    fn entries_follow_the_bias_by_their_own_walk() {
        let (k, pull) = (0.25, 0.5);
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        a.set_pitch_per_force(k);
        a.push_on_grade(1.0, 1.0, pull, Some(0.05), PitchTerms::default());
        let h = a.push_on_grade(1.1, 1.0, pull, Some(0.1), PitchTerms::default());
        assert!(a.merge_newest(h, 0.9, 3.0, pull, Some(0.0), PitchTerms::default()));
        a.push_on_grade(0.9, 2.0, pull, None, PitchTerms::default());
        // Weights 1, 4 (the pair: 0.1 and 0 weighing 1 and 3, 0.025) and 2 (k).
        let walk = (0.05 + 4.0 * 0.025 + 2.0 * k) / 7.0;
        let before = a.combined().unwrap().value_deg;
        let share = a.share();
        a.set_acc_bias_x(0.2);
        let moved = a.combined().unwrap().value_deg - before;
        let expected = (walk + k * share) * 0.2;
        assert!((moved - expected).abs() < 1e-9, "{moved} vs {expected}");
        // Not what the mean dive alone would give.
        assert!((moved - k * (1.0 + share) * 0.2).abs() > 0.01);
        a.restart_shifted(0.0, 0.0, 3.0);
        let restarted = a.combined().unwrap().value_deg;
        a.set_acc_bias_x(0.3);
        let moved = a.combined().unwrap().value_deg - restarted;
        let expected = (walk + k * a.share()) * 0.1;
        assert!((moved - expected).abs() < 1e-9, "{moved} vs {expected}");
        // A walk's answer that no window gives is not taken.
        a.push_on_grade(1.0, 1.0, 0.0, Some(1e6), PitchTerms::default());
        assert_eq!(a.walk_per_bias_deg.last(), Some(&None));
    }

    #[test]
    fn entries_follow_the_dive_and_squat_learnt_since() {
        // Measured with a dive and a squat of 0.2 deg per m/s^2: a stop's pair (its
        // deceleration window's axle point at -1.5 m/s^2, its acceleration window's at
        // +1.6, half of each force's pitch in the value) and a drive-off alone.
        let (d0, s0) = (0.2, 0.2);
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        a.set_pitch_per_force(d0);
        a.set_squat_per_force(s0);
        let braking = PitchTerms::new(0.75, 0.0, d0, s0);
        let pulling = PitchTerms::new(0.0, -0.8, d0, s0);
        let h = a.push_on_grade(1.0, 1.0, 0.0, None, braking);
        assert!(a.merge_newest(h, 1.2, 3.0, 0.0, None, pulling));
        a.push_on_grade(0.8, 2.0, 0.0, None, pulling);
        let before = a.combined().unwrap().value_deg;
        assert!((before - (1.0 + 3.0 * 1.2 + 2.0 * 0.8) / 6.0).abs() < 1e-12);
        // Learnt since: the body dives 0.25 and squats 0.1.
        a.set_pitch_per_force(0.25);
        a.set_squat_per_force(0.1);
        let moved = a.combined().unwrap().value_deg - before;
        let (b, p) = (0.75 * 0.05, -0.8 * -0.1);
        let expected = (b + 3.0 * p + 2.0 * p) / 6.0;
        assert!((moved - expected).abs() < 1e-12, "{moved} vs {expected}");
        // A restart's prior was read with them: it stays.
        a.restart_shifted(0.0, 0.0, 3.0);
        let restarted = a.combined().unwrap().value_deg;
        a.set_squat_per_force(0.3);
        assert_eq!(a.combined().unwrap().value_deg, restarted);
        // Terms no window gives (a damaged state) are dropped, not followed.
        a.push_on_grade(1.0, 1.0, 0.0, None, PitchTerms::new(1e9, 0.0, d0, s0));
        a.sanitize_learnt();
        assert_eq!(a.pitch_terms.last(), Some(&PitchTerms::default()));
    }

    #[test]
    fn restart_from_newest_counts_a_pair_as_two_windows() {
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        for _ in 0..10 {
            a.push(0.2);
        }
        let h = a.push_window(1.6, 1.0);
        assert!(a.merge_newest(h, 2.0, 1.0, 0.0, None, PitchTerms::default()));
        a.push(1.9);
        a.restart_from_newest(3);
        let c = a.combined().unwrap();
        assert!(
            (c.value_deg - (1.8 * 2.0 + 1.9) / 3.0).abs() < 1e-9,
            "{}",
            c.value_deg
        );
        assert_eq!(c.weight, 3.0);
        assert_eq!(a.accepted(), 3);
    }

    #[test]
    fn capacity_drops_oldest() {
        let mut a = Averager::new(Averaging::Mean, 3, 0.2);
        for x in [10.0, 1.0, 1.0, 1.0] {
            a.push(x);
        }
        assert!((a.combined().unwrap().value_deg - 1.0).abs() < 1e-12);
    }

    /// Windows at pulls -1.2..1.2 m/s^2 of a body that dives 0.25 deg per m/s^2 of
    /// braking and shows `share` of it on a grade, on a load of 0.5 deg, with a
    /// deterministic scatter of 0.03 deg.
    fn graded_windows(a: &mut Averager, share: f64) {
        a.set_pitch_per_force(0.25);
        for i in 0..20 {
            let pull = [-1.2, -0.6, 0.0, 0.6, 1.2][i % 5];
            let scatter = if i % 2 == 0 { 0.03 } else { -0.03 };
            a.push_on_grade(
                0.5 + share * 0.25 * pull + scatter,
                1.0,
                pull,
                None,
                PitchTerms::default(),
            );
        }
    }

    #[test]
    fn stops_on_different_grades_tell_how_much_the_body_pitches_there() {
        for mode in [Averaging::Mean, Averaging::Huber] {
            for truth in [0.0, 1.0] {
                let mut a = Averager::new(mode, 64, 0.2);
                graded_windows(&mut a, truth);
                let share = a.share();
                let c = a.combined().unwrap();
                assert!((share - truth).abs() < 0.1, "{mode:?} {truth}: {share}");
                assert!((c.value_deg - 0.5).abs() < 0.02, "{mode:?} {truth}: {c:?}");
                // What is taken out of a window on a 1 m/s^2 pull is that share.
                let out = a.grade_pitch_deg(1.0);
                assert!((out - 0.25 * share).abs() < 1e-9, "{out}");
            }
        }
    }

    #[test]
    fn stops_on_one_grade_keep_the_share_at_its_prior_and_say_so() {
        // Load and grade pitch cannot be told apart on one grade: the prior's share (1)
        // is taken out, and the standard error holds what its uncertainty leaves.
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        a.set_pitch_per_force(0.25);
        let mut level = Averager::new(Averaging::Huber, 64, 0.2);
        for i in 0..20 {
            let scatter = if i % 2 == 0 { 0.03 } else { -0.03 };
            a.push_on_grade(0.7 + scatter, 1.0, 0.8, None, PitchTerms::default());
            level.push_on_grade(0.5 + scatter, 1.0, 0.0, None, PitchTerms::default());
        }
        assert!((a.share() - SHARE_PRIOR).abs() < 1e-9, "{}", a.share());
        let (c, l) = (a.combined().unwrap(), level.combined().unwrap());
        assert!((c.value_deg - 0.5).abs() < 1e-9, "{c:?}");
        assert!(c.std_err_deg > 2.0 * l.std_err_deg, "{c:?} against {l:?}");
    }

    #[test]
    fn a_load_change_keeps_what_the_windows_showed_of_the_share() {
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        graded_windows(&mut a, 0.0);
        let before = a.share();
        a.restart_shifted(1.0, 0.05, 4.0);
        assert!((a.share() - before).abs() < 1e-9, "{} {before}", a.share());
        // A window on a grade under the new load is taken with that share, not the prior.
        a.push_on_grade(1.5, 1.0, 1.0, None, PitchTerms::default());
        assert!(
            a.grade_pitch_deg(1.0).abs() < 0.05,
            "{}",
            a.grade_pitch_deg(1.0)
        );
        // And it survives a save and restore.
        let mut stored: Averager =
            serde_json::from_str(&serde_json::to_string(&a).unwrap()).unwrap();
        let mut restored = Averager::new(Averaging::Huber, 64, 0.2);
        restored.restore_from(&mut stored);
        assert!(
            (restored.share() - a.share()).abs() < 0.05,
            "{}",
            restored.share()
        );
    }

    #[test]
    fn an_average_saved_before_grades_were_kept_reads_as_level() {
        let a = Averager::new(Averaging::Huber, 64, 0.2);
        let mut json = serde_json::to_value(&a).unwrap();
        let obj = json.as_object_mut().unwrap();
        for key in ["pulls_mps2", "per_force_deg", "share_prior"] {
            assert!(obj.remove(key).is_some(), "{key}");
        }
        obj.insert(
            "entries".into(),
            serde_json::json!([[0.4, 1.0], [0.6, 1.0]]),
        );
        let mut old: Averager = serde_json::from_value(json).unwrap();
        old.set_pitch_per_force(0.3);
        assert!((old.combined().unwrap().value_deg - 0.5).abs() < 1e-9);
        old.push_on_grade(0.5, 1.0, 1.0, None, PitchTerms::default());
        assert!(old.combined().unwrap().value_deg.is_finite());
    }

    /// A saved average comes back read with the bias it knew and follows the stops'
    /// bias from there; one saved before entries kept their bias follows nothing.
    #[test]
    fn a_restored_average_follows_the_bias_from_the_one_it_was_read_with() {
        let k = 0.25;
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        a.set_pitch_per_force(k);
        a.set_acc_bias_x(0.1);
        for v in [1.0, 1.2] {
            a.push_on_grade(v, 1.0, 0.0, None, PitchTerms::default());
        }
        a.set_acc_bias_x(0.2);
        let saved = a.combined().unwrap().value_deg;
        let json = serde_json::to_value(&a).unwrap();
        for (old_format, follows) in [(false, true), (true, false)] {
            let mut json = json.clone();
            if old_format {
                let obj = json.as_object_mut().unwrap();
                for key in ["bias_x_mps2", "acc_bias_x_mps2"] {
                    assert!(obj.remove(key).is_some(), "{key}");
                }
            }
            let mut stored: Averager = serde_json::from_value(json).unwrap();
            let mut restored = Averager::new(Averaging::Mean, 64, 0.2);
            restored.restore_from(&mut stored);
            // The old format reads its entries as they were measured.
            let kept = if follows { saved } else { 1.1 };
            let back = restored.combined().unwrap().value_deg;
            assert!((back - kept).abs() < 1e-9, "{back} for {kept}");
            restored.set_acc_bias_x(0.3);
            let moved = restored.combined().unwrap().value_deg - back;
            let expected = if follows {
                k * (1.0 + restored.share()) * 0.1
            } else {
                0.0
            };
            assert!(
                (moved - expected).abs() < 1e-9,
                "{moved}, expected {expected}"
            );
        }
    }

    #[test]
    fn a_restored_average_claims_the_certainty_it_had_when_saved() {
        // Windows that scatter 0.4 deg, as at 300 ug/sqrt(Hz) on rough roads: the prior
        // spread (0.2) must not make the restored estimate look twice as sure.
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        for i in 0..20 {
            a.push(if i % 2 == 0 { 0.9 } else { 0.1 });
        }
        let saved = a.combined().unwrap();
        let mut stored: Averager =
            serde_json::from_str(&serde_json::to_string(&a).unwrap()).unwrap();
        let mut restored = Averager::new(Averaging::Huber, 64, 0.2);
        restored.restore_from(&mut stored);
        let back = restored.combined().unwrap();
        assert!((back.value_deg - saved.value_deg).abs() < 1e-9, "{back:?}");
        assert!(
            (back.std_err_deg / saved.std_err_deg - 1.0).abs() < 0.05,
            "saved {saved:?}, restored {back:?}"
        );
        assert_eq!(restored.accepted(), 20);
    }

    #[test]
    fn a_saved_average_with_implausible_learnt_values_restores_with_the_priors() {
        // A state file edited or damaged into a share far out of range, a negative
        // precision and a negative spread: the value comes back, the rest falls back.
        let mut a = Averager::new(Averaging::Huber, 64, 0.2);
        graded_windows(&mut a, 1.0);
        let mut json = serde_json::to_value(&a).unwrap();
        json["share_prior"] = serde_json::json!({"mean": 1e9, "precision": -5.0});
        json["carried_ss"] = serde_json::json!(-1.0);
        json["carried_dof"] = serde_json::json!(3.0);
        // A bias no accelerometer has, now and on an entry: read as measured.
        json["acc_bias_x_mps2"] = serde_json::json!(1e9);
        json["bias_x_mps2"][0] = serde_json::json!(-1e9);
        let mut stored: Averager = serde_json::from_value(json).unwrap();
        let mut restored = Averager::new(Averaging::Huber, 64, 0.2);
        restored.restore_from(&mut stored);
        let c = restored.combined().unwrap();
        let saved = a.combined().unwrap();
        assert!(
            (c.value_deg - saved.value_deg).abs() < 1e-9,
            "{c:?} for {saved:?}"
        );
        assert!(c.std_err_deg.is_finite(), "{c:?}");
        assert!((restored.share() - a.share()).abs() < 1e-6);
        assert!(restored.carried_ss >= 0.0, "{}", restored.carried_ss);
        restored.set_acc_bias_x(0.3);
        assert_eq!(restored.combined().unwrap().value_deg, c.value_deg);
    }
}
