use leveld::bench::realistic::StopKind;
use leveld::bench::suite::DriveSpec;
use leveld::estimator::{Condition, Estimator, EstimatorConfig, Event};
use leveld::sim::{Input, simulate};

#[test]
#[ignore]
fn lost_gentle() {
    let names = std::env::var("SCS").unwrap_or("urban hilly stop-and-go bumpy".into());
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(8);
    let set: Vec<String> = std::env::var("SET")
        .ok()
        .map(|s| {
            s.split(" ")
                .filter(|x| !x.is_empty())
                .map(String::from)
                .collect()
        })
        .unwrap_or_default();
    for name in names.split_whitespace() {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            for case in spec.cases() {
                let plan = case.plan.clone().unwrap();
                let drive = simulate(&case.scenario);
                let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                }
                for (i, &(t_stop, t_go, kind, acc)) in plan.stops.iter().enumerate() {
                    if i == 0
                        || !matches!(kind, StopKind::Full)
                        || (acc > 0.6 && std::env::var("ALL").is_err())
                    {
                        continue;
                    }
                    let ok = ev.iter().any(|e| matches!(e, Event::WindowAccepted { window, .. }
                        if window.condition == Condition::AccelAfterStop && window.t_s > t_go && window.t_s < t_go + 15.0));
                    if ok {
                        continue;
                    }
                    let near: Vec<String> = ev
                        .iter()
                        .filter_map(|e| match e {
                            Event::StandstillStarted { t_s, .. }
                                if *t_s > t_stop - 3.0 && *t_s < t_go + 3.0 =>
                            {
                                Some(format!("SS@{:.2}", t_s - t_stop))
                            }
                            Event::StandstillEnded { t_s, duration_s }
                                if *t_s > t_stop - 3.0 && *t_s < t_go + 3.0 =>
                            {
                                Some(format!("SE@{:.2}/{:.2}", t_s - t_stop, duration_s))
                            }
                            Event::WindowRejected {
                                t_s,
                                condition,
                                reason,
                            } if *t_s > t_stop - 3.0 && *t_s < t_go + 15.0 => {
                                Some(format!("R{:?}@{:.2}:{:?}", condition, t_s - t_stop, reason))
                            }
                            Event::WindowAccepted { window, .. }
                                if window.t_s > t_stop - 3.0 && window.t_s < t_go + 15.0 =>
                            {
                                Some(format!(
                                    "A{:?}@{:.2}",
                                    window.condition,
                                    window.t_s - t_stop
                                ))
                            }
                            _ => None,
                        })
                        .collect();
                    println!(
                        "{name} {} seed {} stop {i} at {t_stop:.2} dur {:.2} acc {:.2}: {}",
                        case.load,
                        spec.seed,
                        t_go - t_stop,
                        acc,
                        near.join(" ")
                    );
                }
            }
        }
    }
}

#[test]
#[ignore]
fn turned_windows() {
    for name in ["urban", "hilly", "stop-and-go", "bumpy"] {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &[]).unwrap();
        for k in 0..8 {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            for case in spec.cases() {
                let plan = case.plan.clone().unwrap();
                let Some((li, t_ramp_end)) = plan.load_change else {
                    continue;
                };
                let (t_stop, t_go, _, acc) = plan.stops[li];
                let drive = simulate(&case.scenario);
                let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                }
                let near: Vec<String> = ev
                    .iter()
                    .filter_map(|e| match e {
                        Event::LoadChanged { t_s, delta_deg, .. }
                            if *t_s > t_stop - 1.0 && *t_s < t_go + 15.0 =>
                        {
                            Some(format!("L@{:.2}:{:+.2}", t_s - t_stop, delta_deg))
                        }
                        Event::WindowRejected {
                            t_s,
                            condition,
                            reason,
                        } if *t_s > t_stop - 3.0 && *t_s < t_go + 15.0 => {
                            Some(format!("R{:?}@{:.2}:{:?}", condition, t_s - t_stop, reason))
                        }
                        Event::WindowAccepted { window, .. }
                            if window.t_s > t_stop - 3.0 && window.t_s < t_go + 15.0 =>
                        {
                            Some(format!(
                                "A{:?}@{:.2} err {:+.3}",
                                window.condition,
                                window.t_s - t_stop,
                                window.road_to_body_deg - drive.truth_at(window.t_s).load_pitch_deg
                            ))
                        }
                        _ => None,
                    })
                    .collect();
                println!(
                    "{name} {} seed {} stop {li} dur {:.2} ramp_end {:.2} acc {:.2} step {:+.2}: {}",
                    case.load,
                    spec.seed,
                    t_go - t_stop,
                    t_ramp_end - t_stop,
                    acc,
                    drive.truth_at(t_go).load_pitch_deg - drive.truth_at(t_stop).load_pitch_deg,
                    near.join(" ")
                );
            }
        }
    }
}

fn stats(v: &[f64]) -> String {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let r = (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    format!(
        "n {:4} mean {:+.3} rms {:.3} se {:.3}",
        v.len(),
        m,
        r,
        r / n.sqrt()
    )
}

#[test]
#[ignore]
fn bias_split() {
    let names: Vec<String> = std::env::var("SC")
        .unwrap_or("urban".into())
        .split(',')
        .map(String::from)
        .collect();
    let nseeds: u64 = std::env::var("NS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(8);
    let set: Vec<String> = std::env::var("SET")
        .ok()
        .map(|s| {
            s.split(" ")
                .filter(|x| !x.is_empty())
                .map(String::from)
                .collect()
        })
        .unwrap_or_default();
    for name in names {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        let mut groups: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
        for k in 0..nseeds {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            for case in spec.cases() {
                let plan = case.plan.clone().unwrap();
                let drive = simulate(&case.scenario);
                let cfg: EstimatorConfig =
                    toml::from_str(&std::env::var("CFG").unwrap_or_default().replace(';', "\n"))
                        .unwrap();
                let mut est = Estimator::new(cfg).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                }
                for e in &ev {
                    if let Event::WindowAccepted { window: w, .. } = e {
                        let err = w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg;
                        // the stop this window belongs to
                        let stop = plan.stops.iter().find(|s| match w.condition {
                            Condition::DecelBeforeStop => w.t_s >= s.0 - 0.5 && w.t_s <= s.1 + 1.0,
                            _ => w.t_s >= s.1 && w.t_s <= s.1 + 15.0,
                        });
                        let (dur, acc) = stop.map_or((-1.0, -1.0), |s| (s.1 - s.0, s.3));
                        let cls = match w.condition {
                            Condition::DecelBeforeStop => "decel".to_string(),
                            _ => {
                                if acc < 0.0 {
                                    "acc-?".into()
                                } else if acc <= 0.6 {
                                    "acc-gentle".into()
                                } else {
                                    "acc-brisk".into()
                                }
                            }
                        };
                        let d = if dur < 0.0 {
                            "?"
                        } else if dur < 4.0 {
                            "<4s"
                        } else if dur < 8.0 {
                            "4-8s"
                        } else {
                            ">8s"
                        };
                        groups
                            .entry(format!("{} {}", case.load, cls))
                            .or_default()
                            .push(err);
                        groups
                            .entry(format!("{} {} {}", case.load, cls, d))
                            .or_default()
                            .push(err);
                        groups
                            .entry(format!("{} all", case.load))
                            .or_default()
                            .push(err);
                    }
                }
            }
        }
        for (k, v) in &groups {
            println!("{name} {k:24} {}", stats(v));
        }
    }
}

#[test]
#[ignore]
fn acc_windows_dump() {
    let names: Vec<String> = std::env::var("SC")
        .unwrap_or("urban".into())
        .split(',')
        .map(String::from)
        .collect();
    let nseeds: u64 = std::env::var("NS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(8);
    let set: Vec<String> = std::env::var("SET")
        .ok()
        .map(|s| {
            s.split(" ")
                .filter(|x| !x.is_empty())
                .map(String::from)
                .collect()
        })
        .unwrap_or_default();
    for name in names {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        for k in 0..nseeds {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            for case in spec.cases() {
                let plan = case.plan.clone().unwrap();
                let drive = simulate(&case.scenario);
                let cfg: EstimatorConfig =
                    toml::from_str(&std::env::var("CFG").unwrap_or_default().replace(';', "\n"))
                        .unwrap();
                let mut est = Estimator::new(cfg).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                }
                for e in &ev {
                    if let Event::WindowAccepted { window: w, .. } = e {
                        let tr = drive.truth_at(w.t_s);
                        let err = w.road_to_body_deg - tr.load_pitch_deg;
                        let (kind, stop) = match w.condition {
                            Condition::DecelBeforeStop => (
                                "D",
                                plan.stops
                                    .iter()
                                    .find(|s| w.t_s >= s.0 - 0.5 && w.t_s <= s.1 + 1.0),
                            ),
                            _ => (
                                "A",
                                plan.stops
                                    .iter()
                                    .find(|s| w.t_s >= s.1 && w.t_s <= s.1 + 15.0),
                            ),
                        };
                        let Some(&(t0, t1, _, acc)) = stop else {
                            continue;
                        };
                        let g0 = drive.truth_at(t1).grade_deg;
                        let s0 = drive.truth_at(t1).s_m;
                        // grade 1.5 m and 3 m along the walk (ahead for A, behind for D)
                        let at = |ds: f64| {
                            let target = if kind == "A" { s0 + ds } else { s0 - ds };
                            let i = drive.truth.partition_point(|x| {
                                if kind == "A" {
                                    x.s_m < target
                                } else {
                                    x.t_s < t0 - 60.0 || x.s_m < target
                                }
                            });
                            drive.truth[i.min(drive.truth.len() - 1)].grade_deg
                        };
                        println!(
                            "W {name} {} {} {kind} {:.2} {:.2} {:+.4} {:+.4} {:+.4} {:+.4} {:.3} {:.3} {:+.4}",
                            case.load,
                            spec.seed,
                            t1 - t0,
                            acc,
                            err,
                            g0,
                            at(1.5),
                            at(3.0),
                            w.duration_s,
                            w.distance_m,
                            tr.suspension_deg
                        );
                    }
                }
            }
        }
    }
}

#[test]
#[ignore]
fn arm() {
    let nseeds: u64 = std::env::var("NS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(8);
    let set: Vec<String> = std::env::var("SET")
        .ok()
        .map(|s| {
            s.split(" ")
                .filter(|x| !x.is_empty())
                .map(String::from)
                .collect()
        })
        .unwrap_or_default();
    let text = std::fs::read_to_string("scenarios/realistic/urban.toml").unwrap();
    let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
    let (mut sx, mut sz, mut n) = (0.0, 0.0, 0.0);
    for k in 0..nseeds {
        let mut spec = spec0.clone();
        spec.seed = std::env::var("SEED0")
            .ok()
            .map(|x| x.parse::<u64>().unwrap())
            .unwrap_or(spec0.seed)
            + k;
        let case = spec.cases().remove(0);
        let drive = simulate(&case.scenario);
        let cfg = EstimatorConfig::default();
        let prior = nalgebra::Vector3::from(cfg.lever_arm_m);
        let mut est = Estimator::new(cfg).unwrap();
        let mut line = String::new();
        let mut next = 60.0;
        for input in drive.merged() {
            match input {
                Input::Imu(s) => {
                    est.push_imu(s, &mut |_| ());
                    if s.t_s > next {
                        next += 120.0;
                        let a = est.state().lever_fit.unwrap().solve(&prior);
                        line += &format!(" {:.3}", a.x);
                    }
                }
                Input::Wheels(w) => est.push_wheels(w, &mut |_| ()),
            }
        }
        let a = est.state().lever_fit.unwrap().solve(&prior);
        println!(
            "seed {} final x {:.3} z {:.3} |{}",
            spec.seed, a.x, a.z, line
        );
        sx += a.x;
        sz += a.z;
        n += 1.0;
    }
    println!("MEAN x {:.3} z {:.3}", sx / n, sz / n);
}

#[test]
#[ignore]
fn trace_drive() {
    let name = std::env::var("SC").unwrap_or("bumpy".into());
    let seed: u64 = std::env::var("SEED").unwrap().parse().unwrap();
    let load: usize = std::env::var("LOAD").unwrap_or("1".into()).parse().unwrap();
    let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
    let mut spec = DriveSpec::parse_with(&text, &[]).unwrap();
    spec.seed = seed;
    let case = spec.cases().remove(load);
    let drive = simulate(&case.scenario);
    let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
    let mut ev: Vec<Event> = Vec::new();
    for input in drive.merged() {
        match input {
            Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
            Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
        }
    }
    for e in &ev {
        match e {
            Event::WindowAccepted {
                window: w,
                estimate,
            } => println!(
                "{:7.1} A {:?} err {:+.3} dur {:.2} | est {:+.3} (truth {:+.3}) se {:.3} n {} wt {:.2}",
                w.t_s,
                w.condition,
                w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg,
                w.duration_s,
                estimate.road_to_body_deg,
                drive.truth_at(w.t_s).load_pitch_deg,
                estimate.std_err_deg,
                estimate.windows,
                estimate.weight
            ),
            Event::LoadChanged { t_s, delta_deg, .. } => println!("{t_s:7.1} LOAD {delta_deg:+.3}"),
            Event::PitchShifted { t_s, delta_deg, .. } => {
                println!("{t_s:7.1} SHIFT {delta_deg:+.3}")
            }
            _ => {}
        }
    }
}

#[test]
#[ignore]
fn valid_progress() {
    let names = std::env::var("SCS").unwrap_or("urban hilly stop-and-go bumpy".into());
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(8);
    for name in names.split_whitespace() {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let set: Vec<String> = std::env::var("SET")
            .ok()
            .map(|s| {
                s.split(" ")
                    .filter(|x| !x.is_empty())
                    .map(String::from)
                    .collect()
            })
            .unwrap_or_default();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        let (mut ng, mut ngt, mut gerr) = (0, 0, Vec::<f64>::new());
        let (mut nv5, mut nd, mut all_e, mut mae_v) = (0, 0, Vec::<f64>::new(), Vec::<f64>::new());
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            for (li, case) in spec.cases().into_iter().enumerate() {
                let plan = case.plan.clone().unwrap();
                let drive = simulate(&case.scenario);
                let cfg: EstimatorConfig =
                    toml::from_str(&std::env::var("CFG").unwrap_or_default().replace(';', "\n"))
                        .unwrap();
                let mut est = Estimator::new(cfg).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                }
                let t6 = plan.stops.get(6).map(|s| s.0).unwrap_or(f64::MAX);
                let full = plan
                    .stops
                    .iter()
                    .take(6)
                    .filter(|s| matches!(s.2, StopKind::Full))
                    .count();
                let mut last = None;
                let mut first_valid = None;
                let mut nacc = 0;
                let mut errs = Vec::new();
                for e in &ev {
                    if let Event::WindowAccepted {
                        window: w,
                        estimate,
                    } = e
                    {
                        if w.t_s <= t6 {
                            last = Some(*estimate);
                            nacc += 1;
                            errs.push(w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg);
                        }
                        if first_valid.is_none()
                            && estimate.std_err_deg <= 0.06
                            && estimate.weight >= 4.0
                        {
                            first_valid = Some(w.t_s);
                        }
                    }
                }
                let rms =
                    (errs.iter().map(|e| e * e).sum::<f64>() / errs.len().max(1) as f64).sqrt();
                let (se, wt, v) = last
                    .map(|e| {
                        (
                            e.std_err_deg,
                            e.weight,
                            e.road_to_body_deg - drive.truth_at(t6).load_pitch_deg,
                        )
                    })
                    .unwrap_or((9.0, 0.0, 9.0));
                for (i, &(_t_stop, t_go, kind, acc)) in plan.stops.iter().enumerate() {
                    if i == 0 || !matches!(kind, StopKind::Full) || acc > 0.6 {
                        continue;
                    }
                    ngt += 1;
                    if let Some(w) = ev.iter().find_map(|e| match e {
                        Event::WindowAccepted { window, .. }
                            if window.condition == Condition::AccelAfterStop
                                && window.t_s > t_go
                                && window.t_s < t_go + 15.0 =>
                        {
                            Some(*window)
                        }
                        _ => None,
                    }) {
                        ng += 1;
                        gerr.push(w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg);
                    }
                }
                nd += 1;
                if first_valid.is_some_and(|t| t <= t6) {
                    nv5 += 1;
                }
                for e in &ev {
                    if let Event::WindowAccepted {
                        window: w,
                        estimate,
                    } = e
                    {
                        all_e.push(w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg);
                        if first_valid.is_some_and(|t| w.t_s >= t) {
                            mae_v.push(
                                (estimate.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg)
                                    .abs(),
                            );
                        }
                    }
                }
                if std::env::var("V").is_ok() {
                    println!(
                        "{name:12} s{} L{li} t6 {t6:6.0} full {full} acc {nacc:2} wrms {rms:.3} | se {se:.3} wt {wt:5.2} err {v:+.3} | first valid {:?}",
                        spec.seed,
                        first_valid.map(|t| (t, t <= t6))
                    );
                }
            }
        }
        let n = all_e.len() as f64;
        let mean = all_e.iter().sum::<f64>() / n;
        let rms = (all_e.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        let mut a: Vec<f64> = all_e.iter().map(|e| e.abs()).collect();
        a.sort_by(|x, y| x.partial_cmp(y).unwrap());
        let gm = gerr.iter().sum::<f64>() / gerr.len().max(1) as f64;
        let grms = (gerr.iter().map(|e| e * e).sum::<f64>() / gerr.len().max(1) as f64).sqrt();
        println!("GENTLE {name:12} {ng}/{ngt} mean {gm:+.3} rms {grms:.3}");
        println!(
            "SUM {name:12} valid5 {nv5}/{nd} windows {} mean {mean:+.3} rms {rms:.3} p95 {:.3} | est-at-window mae after valid {:.3}",
            all_e.len(),
            a[(0.95 * n) as usize],
            mae_v.iter().sum::<f64>() / mae_v.len().max(1) as f64
        );
    }
}

#[test]
#[ignore]
fn mae_split() {
    let names = std::env::var("SCS").unwrap_or("urban hilly stop-and-go bumpy".into());
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(8);
    let li_want: usize = std::env::var("LOAD")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(1);
    for name in names.split_whitespace() {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &[]).unwrap();
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            let case = spec.cases().remove(li_want);
            let plan = case.plan.clone().unwrap();
            let drive = simulate(&case.scenario);
            let cfg: EstimatorConfig =
                toml::from_str(&std::env::var("CFG").unwrap_or_default().replace(';', "\n"))
                    .unwrap();
            let mut est = Estimator::new(cfg).unwrap();
            let mut next = 0.0;
            let mut valid = false;
            let t_load = plan
                .load_change
                .map(|(i, _)| plan.stops[i].0)
                .unwrap_or(f64::MAX);
            let t_go = plan
                .load_change
                .map(|(i, _)| plan.stops[i].1)
                .unwrap_or(f64::MAX);
            let (mut a, mut b, mut c) = (Vec::<f64>::new(), Vec::<f64>::new(), Vec::<f64>::new());
            for input in drive.merged() {
                let t = match input {
                    Input::Imu(s) => {
                        est.push_imu(s, &mut |_| {});
                        s.t_s
                    }
                    Input::Wheels(w) => {
                        est.push_wheels(w, &mut |_| {});
                        w.t_s
                    }
                };
                if t >= next {
                    next = t + 1.0;
                    if let Some(e) = est.estimate() {
                        if e.std_err_deg <= 0.06 && e.weight >= 4.0 {
                            valid = true;
                        }
                        if valid {
                            let err = e.road_to_body_deg - drive.truth_at(t).load_pitch_deg;
                            if t < t_load {
                                a.push(err)
                            } else if t < t_go + 2.0 {
                                b.push(err)
                            } else {
                                c.push(err)
                            }
                        }
                    }
                }
            }
            let m = |v: &[f64]| v.iter().map(|x| x.abs()).sum::<f64>() / v.len().max(1) as f64;
            let n = (a.len() + b.len() + c.len()) as f64;
            let all =
                (m(&a) * a.len() as f64 + m(&b) * b.len() as f64 + m(&c) * c.len() as f64) / n;
            println!(
                "{name:12} s{} all {all:.3} | before n{:4} {:.3} | during n{:3} {:.3} | after n{:4} {:.3} (mean {:+.3})",
                spec.seed,
                a.len(),
                m(&a),
                b.len(),
                m(&b),
                c.len(),
                m(&c),
                c.iter().sum::<f64>() / c.len().max(1) as f64
            );
        }
    }
}

#[test]
#[ignore]
fn load_probe() {
    let names = std::env::var("SCS").unwrap_or("urban hilly stop-and-go bumpy".into());
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(8);
    for name in names.split_whitespace() {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let set: Vec<String> = std::env::var("SET")
            .ok()
            .map(|s| {
                s.split(" ")
                    .filter(|x| !x.is_empty())
                    .map(String::from)
                    .collect()
            })
            .unwrap_or_default();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = std::env::var("SEED0")
                .ok()
                .map(|x| x.parse::<u64>().unwrap())
                .unwrap_or(spec0.seed)
                + k;
            let case = spec.cases().remove(1);
            let plan = case.plan.clone().unwrap();
            let Some((li, t_ramp_end)) = plan.load_change else {
                continue;
            };
            let (t_stop, t_go, _, _) = plan.stops[li];
            let drive = simulate(&case.scenario);
            let cfg: EstimatorConfig =
                toml::from_str(&std::env::var("CFG").unwrap_or_default().replace(';', "\n"))
                    .unwrap();
            let mut est = Estimator::new(cfg).unwrap();
            let mut ev: Vec<(f64, Event)> = Vec::new();
            let (mut e0, mut e1, mut e2) = (None, None, None);
            for input in drive.merged() {
                let t = match input {
                    Input::Imu(s) => {
                        est.push_imu(s, &mut |e| ev.push((s.t_s, e)));
                        s.t_s
                    }
                    Input::Wheels(w) => {
                        est.push_wheels(w, &mut |e| ev.push((w.t_s, e)));
                        w.t_s
                    }
                };
                if e0.is_none() && t >= t_stop {
                    e0 = est.estimate().map(|e| e.road_to_body_deg);
                }
                if e1.is_none() && t >= t_go {
                    e1 = est.estimate().map(|e| e.road_to_body_deg);
                }
                if e2.is_none()
                    && t >= t_go
                        + std::env::var("KEPT")
                            .ok()
                            .map(|x| x.parse::<f64>().unwrap())
                            .unwrap_or(1.0)
                {
                    e2 = est.estimate().map(|e| e.road_to_body_deg);
                }
            }
            let before = drive.truth_at(t_stop).load_pitch_deg;
            let after = drive.truth_at(t_go).load_pitch_deg;
            let d1 = e1.zip(e0).map(|(a, b)| a - b - (after - before));
            let d2 = e2.zip(e0).map(|(a, b)| a - b - (after - before));
            println!(
                "{name:12} s{} stop {:.1}-{:.1} ({:.1} s) ramp end {:.1} step {:+.3} | err at go {:?} kept {:?}",
                spec.seed,
                t_stop,
                t_go,
                t_go - t_stop,
                t_ramp_end,
                after - before,
                d1.map(|x| (x * 1000.0).round() / 1000.0),
                d2.map(|x| (x * 1000.0).round() / 1000.0)
            );
            let ss = ev.iter().find_map(|(_, e)| match e {
                Event::StandstillStarted { t_s, .. } if *t_s > t_stop - 1.0 && *t_s < t_go => {
                    Some(*t_s - t_stop)
                }
                _ => None,
            });
            let lc = ev.iter().find_map(|(_, e)| match e {
                Event::LoadChanged { t_s, delta_deg, .. }
                    if *t_s > t_stop && *t_s < t_go + 20.0 =>
                {
                    Some((*t_s - t_stop, *delta_deg - (after - before)))
                }
                _ => None,
            });
            println!(
                "LC {name:12} s{} ss {:?} ramp {:.2}-{:.2} go {:.2} lc {:?}",
                spec.seed,
                ss.map(|x| (x * 100.0).round() / 100.0),
                t_ramp_end - t_stop - 3.0,
                t_ramp_end - t_stop,
                t_go - t_stop,
                lc.map(|(a, b)| ((a * 100.0).round() / 100.0, (b * 1000.0).round() / 1000.0))
            );
            if d1.is_some_and(|x| x.abs() > 0.1) && std::env::var("V").is_ok() {
                for (t, e) in &ev {
                    if *t > t_stop - 3.0 && *t < t_go + 20.0 {
                        match e {
                            Event::SampleDropped { .. } => {}
                            _ => println!("    {:+7.2} {:?}", t - t_stop, e),
                        }
                    }
                }
            }
        }
    }
}

#[test]
#[ignore]
fn susp_trace() {
    let name = std::env::var("SC").unwrap_or("urban".into());
    let seed: u64 = std::env::var("SEED").unwrap().parse().unwrap();
    let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
    let mut spec = DriveSpec::parse_with(&text, &[]).unwrap();
    spec.seed = seed;
    let case = spec.cases().remove(1);
    let plan = case.plan.clone().unwrap();
    let (li, _) = plan.load_change.unwrap();
    let (t_stop, t_go, _, _) = plan.stops[li];
    let drive = simulate(&case.scenario);
    let mut t = t_stop - 1.0;
    while t < t_go + 0.5 {
        let tr = drive.truth_at(t);
        println!(
            "{:+6.2} v {:.3} load {:+.3} susp {:+.3} sum {:+.3}",
            t - t_stop,
            tr.v_mps,
            tr.load_pitch_deg,
            tr.suspension_deg,
            tr.load_pitch_deg + tr.suspension_deg
        );
        t += 0.1;
    }
}

#[test]
#[ignore]
fn count_shifts() {
    let seed0: u64 = std::env::var("SEED0")
        .ok()
        .map(|x| x.parse().unwrap())
        .unwrap_or(0);
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(8);
    for name in ["urban", "hilly", "stop-and-go", "bumpy"] {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &[]).unwrap();
        let (mut n, mut good, mut bad) = (0, 0, 0);
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = if seed0 > 0 { seed0 } else { spec0.seed } + k;
            for case in spec.cases() {
                let drive = simulate(&case.scenario);
                let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                let mut before = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                    before.push(0);
                }
                for e in &ev {
                    if let Event::PitchShifted {
                        t_s,
                        delta_deg,
                        estimate,
                    } = e
                    {
                        n += 1;
                        let after = estimate.unwrap().road_to_body_deg
                            - drive.truth_at(*t_s).load_pitch_deg;
                        let prior = after - delta_deg;
                        if after.abs() < prior.abs() {
                            good += 1
                        } else {
                            bad += 1
                        }
                    }
                }
            }
        }
        println!("SHIFTS {name:12} {n} closer {good} farther {bad}");
    }
}

#[test]
#[ignore]
fn grade_k() {
    let names = std::env::var("SCS").unwrap_or("hilly".into());
    let set: Vec<String> = std::env::var("SET")
        .ok()
        .map(|s| {
            s.split(" ")
                .filter(|x| !x.is_empty())
                .map(String::from)
                .collect()
        })
        .unwrap_or_default();
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(4);
    for name in names.split_whitespace() {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = spec0.seed + k;
            let case = spec.cases().remove(0);
            let drive = simulate(&case.scenario);
            let cfg: EstimatorConfig =
                toml::from_str(&std::env::var("CFG").unwrap_or_default().replace(';', "\n"))
                    .unwrap();
            let mut est = Estimator::new(cfg).unwrap();
            let mut ev: Vec<Event> = Vec::new();
            for input in drive.merged() {
                match input {
                    Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                    Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                }
            }
            let mut by: Vec<(f64, f64, String)> = Vec::new();
            for e in &ev {
                if let Event::WindowAccepted { window: w, .. } = e {
                    let err = w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg;
                    by.push((w.road_slope_deg, err, format!("{:?}", w.condition)));
                }
            }
            let fit = |v: &[(f64, f64, String)]| {
                let n = v.len() as f64;
                let mx = v.iter().map(|x| x.0).sum::<f64>() / n;
                let my = v.iter().map(|x| x.1).sum::<f64>() / n;
                let sxy: f64 = v.iter().map(|x| (x.0 - mx) * (x.1 - my)).sum();
                let sxx: f64 = v.iter().map(|x| (x.0 - mx).powi(2)).sum();
                (my, sxy / sxx, n)
            };
            let (m, b, n) = fit(&by);
            println!(
                "{name} s{} k_true {:.3} k_learnt {:.3} | windows {n} mean err {m:+.3} err per deg of slope {b:+.4} (k*g*pi/180 = {:.4})",
                spec.seed,
                case.scenario.vehicle.pitch_per_accel_deg,
                est.pitch_per_force_deg(),
                case.scenario.vehicle.pitch_per_accel_deg * 9.81 * std::f64::consts::PI / 180.0
            );
        }
    }
}

#[test]
#[ignore]
fn short_stops() {
    use leveld::bench::realistic::RealisticSpec;
    let text = std::fs::read_to_string("scenarios/realistic/urban.toml").unwrap();
    let delay: f64 = std::env::var("DELAY")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(0.06);
    for seed in [31u64, 32, 33] {
        let mut s = DriveSpec::parse(&text).unwrap();
        s.seed = seed;
        s.stops = 10;
        s.distance_km = Some(2.5);
        s.turn_share = 0.0;
        s.hold_s = [8.0, 15.0];
        s.realistic = Some(RealisticSpec {
            gentle_start_share: 1.0,
            rolling_stop_share: 0.0,
            short_stop_share: 1.0,
            door_shock_share: 0.0,
            imu_gap_share: 0.0,
            ..RealisticSpec::default()
        });
        let mut sen = s.sensors.clone().unwrap();
        sen.wheel_delay_s = delay;
        s.sensors = Some(sen);
        let case = &s.cases()[0];
        let plan = case.plan.clone().unwrap();
        let drive = simulate(&case.scenario);
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let mut ev: Vec<Event> = Vec::new();
        for input in drive.merged() {
            match input {
                Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
            }
        }
        for (i, &(t_stop, t_go, _kind, acc)) in plan.stops.iter().enumerate() {
            let near: Vec<String> = ev
                .iter()
                .filter_map(|e| match e {
                    Event::StandstillStarted { t_s, .. }
                        if *t_s > t_stop - 3.0 && *t_s < t_go + 3.0 =>
                    {
                        Some(format!("SS@{:.2}", t_s - t_stop))
                    }
                    Event::StandstillEnded { t_s, duration_s }
                        if *t_s > t_stop - 3.0 && *t_s < t_go + 3.0 =>
                    {
                        Some(format!("SE@{:.2}/{:.2}", t_s - t_stop, duration_s))
                    }
                    Event::WindowRejected {
                        t_s,
                        condition,
                        reason,
                    } if *t_s > t_stop - 3.0 && *t_s < t_go + 15.0 => {
                        Some(format!("R{:?}@{:.2}:{:?}", condition, t_s - t_stop, reason))
                    }
                    Event::WindowAccepted { window, .. }
                        if window.t_s > t_stop - 3.0 && window.t_s < t_go + 15.0 =>
                    {
                        Some(format!(
                            "A{:?}@{:.2} err {:+.3}",
                            window.condition,
                            window.t_s - t_stop,
                            window.road_to_body_deg - drive.truth_at(window.t_s).load_pitch_deg
                        ))
                    }
                    _ => None,
                })
                .collect();
            println!(
                "seed {seed} stop {i} at {t_stop:.2} dur {:.2} acc {acc:.2}: {}",
                t_go - t_stop,
                near.join(" ")
            );
        }
    }
}

#[test]
#[ignore]
fn big_windows() {
    let names = std::env::var("SCS").unwrap_or("urban hilly stop-and-go bumpy".into());
    let ns: u64 = std::env::var("NS")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(8);
    let thr: f64 = std::env::var("THR")
        .ok()
        .map(|s| s.parse().unwrap())
        .unwrap_or(0.8);
    for name in names.split_whitespace() {
        let text = std::fs::read_to_string(format!("scenarios/realistic/{name}.toml")).unwrap();
        let set: Vec<String> = std::env::var("SET")
            .ok()
            .map(|s| {
                s.split(' ')
                    .filter(|x| !x.is_empty())
                    .map(String::from)
                    .collect()
            })
            .unwrap_or_default();
        let spec0 = DriveSpec::parse_with(&text, &set).unwrap();
        let (mut nbig, mut nall) = (0, 0);
        for k in 0..ns {
            let mut spec = spec0.clone();
            spec.seed = spec0.seed + k;
            for case in spec.cases() {
                let plan = case.plan.clone().unwrap();
                let drive = simulate(&case.scenario);
                let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
                let mut ev: Vec<Event> = Vec::new();
                for input in drive.merged() {
                    match input {
                        Input::Imu(s) => est.push_imu(s, &mut |e| ev.push(e)),
                        Input::Wheels(w) => est.push_wheels(w, &mut |e| ev.push(e)),
                    }
                }
                let mut last_ss = (0.0, 0.0);
                for e in &ev {
                    if let Event::StandstillEnded { t_s, duration_s } = e {
                        last_ss = (*t_s, *duration_s);
                    }
                    if let Event::WindowAccepted { window: w, .. } = e {
                        nall += 1;
                        let err = w.road_to_body_deg - drive.truth_at(w.t_s).load_pitch_deg;
                        if err.abs() < thr {
                            continue;
                        }
                        nbig += 1;
                        let stop = plan
                            .stops
                            .iter()
                            .enumerate()
                            .find(|(_, s)| match w.condition {
                                Condition::DecelBeforeStop => {
                                    w.t_s >= s.0 - 0.5 && w.t_s <= s.1 + 1.0
                                }
                                _ => w.t_s >= s.1 && w.t_s <= s.1 + 15.0,
                            });
                        let desc = stop.map_or("?".to_string(), |(i, s)| format!("stop {i} dur {:.2} acc {:.2} kind {:?} | SS {:+.2}..{:+.2} rel stop; win start {:+.2} rel go", s.1 - s.0, s.3, s.2, last_ss.0 - last_ss.1 - s.0, last_ss.0 - s.0, w.start_s - s.1));
                        let tr = drive.truth_at(w.start_s);
                        let tr_end = drive.truth_at(w.t_s);
                        let true_pitch = tr.grade_deg + tr.load_pitch_deg + tr.suspension_deg;
                        println!(
                            "REF err {:+.2} (susp at start {:+.2}) | slope {:+.2} true grade start {:+.2} end {:+.2}",
                            w.imu_pitch_deg - true_pitch,
                            tr.suspension_deg,
                            w.road_slope_deg,
                            tr.grade_deg,
                            tr_end.grade_deg
                        );
                        println!(
                            "{name} {} s{} {:?} t {:.1} err {err:+.2} D {:.2} T {:.2} | {desc} | last SS end {:.1} dur {:.2}",
                            case.load,
                            spec.seed,
                            w.condition,
                            w.t_s,
                            w.distance_m,
                            w.duration_s,
                            last_ss.0,
                            last_ss.1
                        );
                    }
                }
            }
        }
        println!("SUM {name} big {nbig} of {nall}");
    }
}
