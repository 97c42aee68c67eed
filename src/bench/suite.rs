//! Drive scenarios of the accuracy benchmark, described in TOML files (`scenarios/`)
//! and expanded into simulator scenarios with a fixed seed.

use crate::sim::noise::Gauss;
use crate::sim::scenario::{Scenario, Sensors, SpeedProfile, Vehicle};
use serde::{Deserialize, Serialize};

/// One scenario file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSpec {
    pub name: String,
    pub seed: u64,
    /// Stops after the start.
    pub stops: usize,
    /// Approximate length of the drive, km (cruise distances are scaled to it).
    #[serde(default)]
    pub distance_km: Option<f64>,
    /// Grade at each stop, percent: a fixed list cycled, or drawn from +-grade_max_pct.
    #[serde(default)]
    pub grades_pct: Vec<f64>,
    #[serde(default)]
    pub grade_max_pct: f64,
    /// Ranges [min, max] the legs are drawn from.
    pub top_kmh: [f64; 2],
    pub accel_mps2: [f64; 2],
    pub brake_mps2: [f64; 2],
    pub hold_s: [f64; 2],
    /// Share of stops followed by a 90 degree turn at the intersection.
    #[serde(default)]
    pub turn_share: f64,
    /// Share of turns that start right at the stop line (inside the window).
    #[serde(default)]
    pub turn_at_line_share: f64,
    /// Road-to-body pitch per load case, deg.
    pub loads: Vec<Load>,
    /// Stop (1-based) at which the second load case is loaded in ("5P" runs).
    #[serde(default)]
    pub load_change_at_stop: Option<usize>,
    #[serde(default)]
    pub rough_road_mps2: f64,
    /// Speed bumps 3 m after this share of stops.
    #[serde(default)]
    pub bump_share: f64,
    /// Put this share of stops right on a grade change.
    #[serde(default)]
    pub stop_on_grade_change_share: f64,
    #[serde(default)]
    pub sensors: Option<Sensors>,
    /// The effects of a realistic drive (see `bench::realistic`); present in the
    /// `scenarios/realistic/` family.
    #[serde(default)]
    pub realistic: Option<super::realistic::RealisticSpec>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Load {
    pub name: String,
    pub pitch_deg: f64,
}

/// A scenario with its load case and where its stops are.
#[derive(Debug, Clone)]
pub struct Case {
    pub scenario_name: String,
    /// The scenario file's seed this case was drawn with.
    pub seed: u64,
    pub load: String,
    pub scenario: Scenario,
    /// Stops of a realistic drive, for the per-stop checks.
    pub plan: Option<super::realistic::StopPlan>,
}

impl DriveSpec {
    pub fn parse(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    /// Parse with settings changed: each of `set` is `key=value`, the key dotted into
    /// the scenario's tables (`sensors.imu_rate_hz`), the value in TOML (`200`,
    /// `[1.0, 1.1]`, `"name"`).
    pub fn parse_with(text: &str, set: &[String]) -> anyhow::Result<Self> {
        use anyhow::{Context, bail};
        let mut table: toml::Table = toml::from_str(text)?;
        for s in set {
            let Some((key, value)) = s.split_once('=') else {
                bail!("--set {s}: write KEY=VALUE, for example sensors.imu_rate_hz=200");
            };
            let value: toml::Table = toml::from_str(&format!("v = {}", value.trim()))
                .with_context(|| {
                    format!("--set {s}: the value is not TOML (quote text: name=\"mine\")")
                })?;
            let value = value.get("v").cloned().context("a TOML value")?;
            let parts: Vec<&str> = key.trim().split('.').collect();
            let (last, path) = parts.split_last().context("an empty key")?;
            let mut t = &mut table;
            for p in path {
                t = t
                    .entry(p.to_string())
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                    .as_table_mut()
                    .with_context(|| format!("--set {s}: `{p}` is not a table"))?;
            }
            t.insert(last.to_string(), value);
        }
        let spec: Self = toml::Value::Table(table).try_into()?;
        if let Some(r) = &spec.realistic {
            r.check()?;
        }
        if let Some(s) = &spec.sensors {
            s.check()?;
        }
        Ok(spec)
    }

    /// One simulator scenario per load case. The second load case, when
    /// `load_change_at_stop` is set, starts in the first and is loaded at that stop.
    pub fn cases(&self) -> Vec<Case> {
        let mut out = Vec::new();
        for (li, load) in self.loads.iter().enumerate() {
            let (scenario, plan) = match &self.realistic {
                Some(r) => {
                    let (sc, plan) = super::realistic::build(self, r, li);
                    (sc, Some(plan))
                }
                None => (self.build(li), None),
            };
            out.push(Case {
                scenario_name: self.name.clone(),
                seed: self.seed,
                load: load.name.clone(),
                scenario,
                plan,
            });
        }
        out
    }

    fn build(&self, load_idx: usize) -> Scenario {
        let mut g = Gauss::new(self.seed);
        let pick = |g: &mut Gauss, r: [f64; 2]| r[0] + (r[1] - r[0]) * g.uniform();
        let mut legs = Vec::new();
        for _ in 0..self.stops {
            let rapid = g.uniform() < 0.4;
            let accel = if rapid {
                pick(
                    &mut g,
                    [
                        0.5 * (self.accel_mps2[0] + self.accel_mps2[1]),
                        self.accel_mps2[1],
                    ],
                )
            } else {
                pick(
                    &mut g,
                    [
                        self.accel_mps2[0],
                        0.5 * (self.accel_mps2[0] + self.accel_mps2[1]),
                    ],
                )
            };
            legs.push((
                pick(&mut g, self.hold_s),
                accel,
                pick(&mut g, self.top_kmh),
                5.0,
                pick(&mut g, self.brake_mps2),
            ));
        }
        // Scale the cruise of each leg so the drive has the requested length.
        if let Some(km) = self.distance_km {
            let base: f64 = legs
                .iter()
                .map(|l| {
                    let v = l.2 / 3.6;
                    v * v / (2.0 * l.1) + v * v / (2.0 * l.4)
                })
                .sum();
            let per_leg = ((km * 1000.0 - base) / legs.len() as f64).max(20.0);
            for l in &mut legs {
                l.3 = per_leg / (l.2 / 3.6);
            }
        }
        let (speed, stops): (SpeedProfile, Vec<f64>) = crate::sim::presets::city_legs(&legs, 8.0);
        let grades: Vec<f64> = if !self.grades_pct.is_empty() {
            (0..stops.len())
                .map(|i| self.grades_pct[i % self.grades_pct.len()])
                .collect()
        } else {
            (0..stops.len())
                .map(|_| (2.0 * g.uniform() - 1.0) * self.grade_max_pct)
                .collect()
        };
        let mut road = crate::sim::presets::road_around_stops(&stops, &grades);
        // Stops right on a grade change: move the change onto the stop.
        for (i, &s) in stops.iter().enumerate().skip(1) {
            if g.uniform() < self.stop_on_grade_change_share {
                let gi = grades[i];
                let other = (gi + 4.0).min(self.grade_max_pct.max(4.0));
                let deg = |p: f64| (p / 100.0).atan().to_degrees();
                road.grade_deg.retain(|k| (k.0 - s).abs() > 6.0);
                road.grade_deg.push((s - 0.5, deg(gi)));
                road.grade_deg.push((s + 0.5, deg(other)));
                road.grade_deg.sort_by(|a, b| a.0.total_cmp(&b.0));
            }
        }
        add_bumps(&mut road, &stops, self.bump_share, &mut g);
        // Turns after some stops: 90 degrees on a 15 m radius.
        for &s in stops.iter() {
            if g.uniform() < self.turn_share {
                let start = if g.uniform() < self.turn_at_line_share {
                    s
                } else {
                    s + 12.0
                };
                let dir = if g.uniform() < 0.5 { 1.0 } else { -1.0 };
                road.curves.push((
                    start,
                    start + 15.0 * std::f64::consts::FRAC_PI_2,
                    dir / 15.0,
                ));
            }
        }
        let base_load = self.loads[0].pitch_deg;
        let (load0, changes) = match (load_idx, self.load_change_at_stop) {
            (0, _) => (base_load, Vec::new()),
            (li, Some(k)) if k < legs.len() => {
                // Stop k is the hold that starts leg k: the legs before it, then 2 s
                // into the hold (which lasts at least hold_s[0]).
                let t: f64 = legs[..k]
                    .iter()
                    .map(|l| l.0 + l.2 / 3.6 / l.1 + l.3 + l.2 / 3.6 / l.4)
                    .sum::<f64>()
                    + 2.0;
                (base_load, vec![(t, self.loads[li].pitch_deg, 3.0)])
            }
            (li, _) => (self.loads[li].pitch_deg, Vec::new()),
        };
        Scenario {
            speed,
            road,
            load_pitch_deg: load0,
            load_changes: changes,
            vehicle: Vehicle {
                rough_road_mps2: self.rough_road_mps2,
                ..Vehicle::default()
            },
            sensors: self.sensors.clone().unwrap_or(Sensors {
                acc_bias_mps2: [0.05, -0.03, 0.08],
                gyro_bias_dps: [0.2, -0.3, 0.1],
                ..Sensors::default()
            }),
            shocks: Vec::new(),
            imu_gaps: Vec::new(),
            seed: self.seed.wrapping_mul(31).wrapping_add(load_idx as u64),
        }
    }
}

/// Speed bumps: a 7 cm hump over 3 m, 3 m past each of a `share` of the stops.
pub(crate) fn add_bumps(road: &mut crate::sim::Road, stops: &[f64], share: f64, g: &mut Gauss) {
    for &s in stops.iter() {
        if g.uniform() < share {
            let base = road.grade(s + 3.0).0.to_degrees();
            let hump = (0.07f64 / 1.5).atan().to_degrees();
            road.grade_deg.retain(|k| k.0 < s + 2.5 || k.0 > s + 6.5);
            road.grade_deg.extend([
                (s + 2.9, base),
                (s + 3.0, base + hump),
                (s + 4.4, base + hump),
                (s + 4.6, base - hump),
                (s + 5.9, base - hump),
                (s + 6.0, base),
            ]);
            road.grade_deg.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::DriveSpec;

    const URBAN: &str = include_str!("../../scenarios/realistic/urban.toml");

    #[test]
    fn settings_are_changed_by_dotted_keys_and_mistakes_are_named() {
        let set = |s: &[&str]| {
            let owned: Vec<String> = s.iter().map(|x| x.to_string()).collect();
            DriveSpec::parse_with(URBAN, &owned)
        };
        let s = set(&[
            "sensors.imu_rate_hz=200",
            "realistic.pitch_freq_hz=[1.0, 1.1]",
            "name=\"urban-200hz\"",
        ])
        .unwrap();
        assert_eq!(s.sensors.unwrap().imu_rate_hz, 200.0);
        assert_eq!(s.realistic.unwrap().pitch_freq_hz, [1.0, 1.1]);
        assert_eq!(s.name, "urban-200hz");
        // A misspelt key, a value that is not TOML, a path through a value.
        for bad in [
            "sensors.imu_rate=200",
            "sensors.imu_rate_hz=fast",
            "name.x=1",
            "seed",
            "realistic.road_roughness_1e6_m3=-1.0",
            "realistic.heave_freq_hz=[0.0, 1.2]",
            "realistic.heave_damping=[0.3, 0.2]",
            "sensors.imu_rate_hz=-5.0",
            "sensors.wheel_scale=0.0",
            "sensors.imu_jitter_ms=[1.5, 0.2]",
            "realistic.idle_vibration_mps2=-0.1",
            "realistic.idle_vibration_hz=1.0",
            "realistic.cross_slope_pct=30.0",
            "realistic.heave_per_accel_mm=[3.0, 1.0]",
            "realistic.heave_per_accel_mm=[0.0, 50.0]",
            "realistic.squat_share=[0.8, 0.5]",
            "realistic.squat_share=[-0.1, 0.5]",
            "realistic.squat_share=[0.5, 3.0]",
        ] {
            assert!(set(&[bad]).is_err(), "{bad} was accepted");
        }
    }
}
