//! Combination of accepted windows into one road-to-body pitch (eq. 17 and a robust variant).

use super::config::Averaging;
use serde::{Deserialize, Serialize};

/// Fixed-capacity set of weighted window values for the current load, deg.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Averager {
    mode: Averaging,
    capacity: usize,
    sigma_prior_deg: f64,
    /// (value deg, weight) oldest first; a load-change prior has weight > 1.
    entries: Vec<(f64, f64)>,
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

/// See [`Averager::fit`].
struct Fit {
    value_deg: f64,
    weight: f64,
    ss: f64,
    dof: f64,
}

/// Combined estimate with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Combined {
    pub value_deg: f64,
    /// Standard error of the combined value, deg.
    pub std_err_deg: f64,
    /// Effective number of windows behind the value (a load-change prior counts as its weight).
    pub weight: f64,
}

impl Averager {
    pub fn new(mode: Averaging, capacity: usize, sigma_prior_deg: f64) -> Self {
        Self {
            mode,
            capacity,
            sigma_prior_deg,
            entries: Vec::with_capacity(capacity),
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
        self.push_weighted(value_deg, weight);
        self.accepted = self.accepted.saturating_add(1);
        PairHandle(self.changes)
    }

    /// Fold a window into the newest entry, if that is still the one `handle` was
    /// given for: the two become one entry, their weighted mean with the sum of their
    /// weights. Windows of one stop share its standstill reference and their errors
    /// partly cancel, so the pair is one measurement, not two independent ones.
    /// Returns false (and changes nothing) when the entry is gone or was followed.
    pub fn merge_newest(&mut self, handle: PairHandle, value_deg: f64, weight: f64) -> bool {
        if handle.0 != self.changes {
            return false;
        }
        let Some(e) = self.entries.last_mut() else {
            return false;
        };
        let w = e.1 + weight;
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
        let (value_deg, _) = self.entries.pop()?;
        self.pair_bits >>= 1;
        self.accepted = self.accepted.saturating_sub(1);
        self.changes = self.changes.wrapping_add(1);
        Some(value_deg)
    }

    fn push_weighted(&mut self, value_deg: f64, w: f64) {
        if self.entries.len() == self.capacity {
            self.entries.remove(0);
        }
        self.entries.push((value_deg, w));
        self.changes = self.changes.wrapping_add(1);
        self.pair_bits <<= 1;
    }

    /// Restart from a new load: the previous estimate shifted by `delta_deg` (known to
    /// `delta_sd_deg`) is kept as a prior worth at most `prior_weight` windows, and no
    /// more than its uncertainty allows: its standard error and the step's, against the
    /// spread of a typical window. Older windows are dropped.
    pub fn restart_shifted(&mut self, delta_deg: f64, delta_sd_deg: f64, prior_weight: f64) {
        let prior = self.combined();
        if let Some(f) = self.fit() {
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
                self.push_weighted(c.value_deg + delta_deg, w);
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
        self.entries.drain(..self.entries.len() - keep);
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
        let f = self.fit()?;
        // Spread of a window of weight 1, pooled with a prior worth two windows so that
        // a handful of agreeing windows does not claim an implausibly small error.
        let k0 = 2.0;
        let num = k0 * self.sigma_prior_deg.powi(2) + self.carried_ss + f.ss;
        let sigma = (num / (k0 + self.carried_dof + f.dof)).sqrt();
        Some(Combined {
            value_deg: f.value_deg,
            std_err_deg: sigma / f.weight.sqrt(),
            weight: f.weight,
        })
    }

    /// Value of the current entries and what their residuals show of the spread of a
    /// window of weight 1. Each residual is clipped where the Huber estimate stops
    /// following it (a window it discounts moves the value, and so its error, no
    /// further); dividing by the square of the share of weight it follows turns that
    /// clipped sum into the M-estimate's variance (1.03 of a Gaussian's spread at 1.5
    /// sigma). Both change smoothly as a window crosses the clip. One degree of freedom
    /// per entry: a pair of windows or a load-change prior is one residual.
    fn fit(&mut self) -> Option<Fit> {
        if self.entries.is_empty() {
            return None;
        }
        let wsum: f64 = self.entries.iter().map(|e| e.1).sum();
        let (value, clip) = match self.mode {
            // One entry (a restored or restarted estimate) is its own value, exactly.
            _ if self.entries.len() == 1 => (self.entries[0].0, f64::INFINITY),
            Averaging::Mean => {
                let mean = self.entries.iter().map(|e| e.0 * e.1).sum::<f64>() / wsum;
                (mean, f64::INFINITY)
            }
            Averaging::Huber => self.huber(),
        };
        let (mut ss, mut followed_w) = (0.0, 0.0);
        for &(x, w) in &self.entries {
            let r = (x - value).abs();
            let c = entry_clip(clip, w);
            ss += w * r.min(c).powi(2);
            // The Huber weight: 1 inside the clip, clip / residual beyond, so that the
            // share moves smoothly as a window crosses the clip.
            followed_w += w * if r > c { c / r } else { 1.0 };
        }
        let share = (followed_w / wsum).max(0.5);
        Some(Fit {
            value_deg: value,
            weight: wsum,
            ss: ss / (share * share),
            dof: (self.entries.len() as f64 - 1.0).max(0.0),
        })
    }

    /// Weighted Huber M-estimate of location, and the residual beyond which it discounts
    /// a window of weight 1 (infinite below three entries). Residuals are measured in
    /// each entry's own spread: a window of weight w is expected to scatter 1/sqrt(w) as
    /// far as one of weight 1, so its clip is that much wider, and the scale is the MAD
    /// of the residuals so normalised. A long, noisy window is then discounted for being
    /// far off by its own standards, not for being noisy, which its weight already says.
    fn huber(&mut self) -> (f64, f64) {
        let n = self.entries.len();
        self.scratch.clear();
        self.scratch.extend(self.entries.iter().map(|e| e.0));
        let med = median(&mut self.scratch);
        if n < 3 {
            let wsum: f64 = self.entries.iter().map(|e| e.1).sum();
            let mean = self.entries.iter().map(|e| e.0 * e.1).sum::<f64>() / wsum;
            return (mean, f64::INFINITY);
        }
        self.scratch.clear();
        self.scratch
            .extend(self.entries.iter().map(|e| (e.0 - med).abs() * e.1.sqrt()));
        // 1.4826 makes the MAD a standard deviation for normal data; the floor keeps
        // identical windows from producing a zero scale.
        let scale = (1.4826 * median(&mut self.scratch)).max(0.02);
        let c = HUBER_CLIP_SIGMA * scale;
        let mut mu = med;
        for _ in 0..20 {
            let (mut num, mut den) = (0.0, 0.0);
            for &(x, w) in &self.entries {
                let r = (x - mu).abs();
                let ci = entry_clip(c, w);
                let hw = if r <= ci { 1.0 } else { ci / r };
                num += w * hw * x;
                den += w * hw;
            }
            let next = num / den;
            if (next - mu).abs() < 1e-9 {
                return (next, c);
            }
            mu = next;
        }
        (mu, c)
    }
}

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
    /// Seed with a restored value worth `weight` windows (`accepted` of them under this load).
    pub fn restore_prior(&mut self, value_deg: f64, weight: f64, accepted: u64) {
        self.entries.clear();
        self.carried_ss = 0.0;
        self.carried_dof = 0.0;
        self.push_weighted(value_deg, weight);
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
        assert!(a.merge_newest(h, 0.0, 0.25));
        let c = a.combined().unwrap();
        assert!((c.weight - 2.25).abs() < 1e-12);
        assert!((c.value_deg - (1.0 + 0.4 + 0.0 * 0.25) / 2.25).abs() < 1e-12);
        assert_eq!(a.accepted(), 3);
        // Used once, and never after another window or a restart.
        assert!(!a.merge_newest(h, 0.0, 1.0));
        let h = a.push_window(0.5, 1.0);
        a.push(0.6);
        assert!(!a.merge_newest(h, 0.0, 1.0));
        let h = a.push_window(0.5, 1.0);
        a.restart_shifted(0.3, 0.05, 4.0);
        assert!(!a.merge_newest(h, 0.0, 1.0));
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
        assert!(a.merge_newest(h, 2.0, 1.0));
        assert_eq!(a.withdraw_newest(h), None);
        assert_eq!(a.accepted(), 6);
    }

    #[test]
    fn restart_from_newest_counts_a_pair_as_two_windows() {
        let mut a = Averager::new(Averaging::Mean, 64, 0.2);
        for _ in 0..10 {
            a.push(0.2);
        }
        let h = a.push_window(1.6, 1.0);
        assert!(a.merge_newest(h, 2.0, 1.0));
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
}
