//! PNG figures of the accuracy benchmark (plotters, bitmap backend).

use super::accuracy::Row;
use anyhow::{Context, Result, bail};
use plotters::prelude::*;
use std::path::Path;

/// TrueType fonts looked for, in order; `LEVELD_FONT` overrides.
const FONTS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

fn register_font() -> Result<()> {
    static DONE: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let r = DONE.get_or_init(|| {
        let candidates: Vec<String> = std::env::var("LEVELD_FONT")
            .into_iter()
            .chain(FONTS.iter().map(|s| s.to_string()))
            .collect();
        for p in &candidates {
            if let Ok(bytes) = std::fs::read(p) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                return plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
                    .map_err(|_| format!("{p} is not a usable font"));
            }
        }
        Err(format!(
            "no TrueType font found ({}); install fonts-dejavu-core or set LEVELD_FONT",
            candidates.join(", ")
        ))
    });
    match r {
        Ok(()) => Ok(()),
        Err(e) => bail!("{e}"),
    }
}

const COLORS: [RGBColor; 4] = [
    RGBColor(0, 90, 181),
    RGBColor(0, 150, 80),
    RGBColor(220, 50, 32),
    RGBColor(150, 100, 0),
];

/// Write `estimate-<scenario>-<load>.png` and `windows-<scenario>-<load>.png` per case.
pub fn write(dir: &Path, rows: &[Row]) -> Result<()> {
    register_font()?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut cases: Vec<(&str, &str)> = rows
        .iter()
        .map(|r| (r.scenario.as_str(), r.load.as_str()))
        .collect();
    cases.dedup();
    for (sc, load) in cases {
        let sel: Vec<&Row> = rows
            .iter()
            .filter(|r| r.scenario == sc && r.load == load)
            .collect();
        estimate_plot(
            &dir.join(format!("estimate-{sc}-{load}.png")),
            sc,
            load,
            &sel,
        )?;
        if let Some(l) = sel.iter().find(|r| r.method == "leveld") {
            histogram(&dir.join(format!("windows-{sc}-{load}.png")), sc, load, l)?;
        }
    }
    Ok(())
}

fn estimate_plot(path: &Path, sc: &str, load: &str, rows: &[&Row]) -> Result<()> {
    let root = BitMapBackend::new(path, (1000, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let t_max = rows
        .iter()
        .flat_map(|r| r.track.last().map(|x| x.0))
        .fold(1.0, f64::max);
    let truth: Vec<(f64, f64)> = rows
        .first()
        .map(|r| r.track.iter().map(|x| (x.0, x.2)).collect())
        .unwrap_or_default();
    let (lo, hi) = truth
        .iter()
        .fold((f64::MAX, f64::MIN), |a, x| (a.0.min(x.1), a.1.max(x.1)));
    let (y0, y1) = (lo - 1.5, hi + 1.5);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("{sc} {load}: road-to-body pitch estimate vs truth"),
            ("sans-serif", 22),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..t_max, y0..y1)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("pitch (deg)")
        .label_style(("sans-serif", 14))
        .draw()?;
    chart
        .draw_series(LineSeries::new(truth, BLACK.stroke_width(3)))?
        .label("truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(3)));
    for (i, r) in rows.iter().enumerate() {
        let c = COLORS[i % COLORS.len()];
        let pts: Vec<(f64, f64)> = r
            .track
            .iter()
            .filter(|x| x.1.is_finite())
            .map(|x| (x.0, x.1.clamp(y0, y1)))
            .collect();
        chart
            .draw_series(LineSeries::new(pts, c.stroke_width(2)))?
            .label(r.method.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    root.present()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn histogram(path: &Path, sc: &str, load: &str, r: &Row) -> Result<()> {
    let root = BitMapBackend::new(path, (700, 420)).into_drawing_area();
    root.fill(&WHITE)?;
    let bin = 0.05;
    let nb = 24i32; // -0.6 .. +0.6 deg
    let mut counts = vec![0u32; nb as usize];
    for e in &r.window_errors {
        let i = ((e + 0.6) / bin).floor() as i32;
        counts[i.clamp(0, nb - 1) as usize] += 1;
    }
    let ymax = counts.iter().copied().max().unwrap_or(1) + 1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "{sc} {load}: leveld single-window errors ({} windows)",
                r.window_errors.len()
            ),
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(45)
        .build_cartesian_2d(-0.6f64..0.6f64, 0u32..ymax)?;
    chart
        .configure_mesh()
        .x_desc("window error (deg)")
        .y_desc("windows")
        .label_style(("sans-serif", 14))
        .draw()?;
    chart.draw_series(counts.iter().enumerate().map(|(i, &c)| {
        let x0 = -0.6 + i as f64 * bin;
        Rectangle::new([(x0, 0), (x0 + bin * 0.9, c)], COLORS[0].filled())
    }))?;
    root.present()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
