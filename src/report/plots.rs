//! SVG plots of a run, drawn with plotters from a [`TrajectoryRecorder`]: joint angles (the
//! paper's Fig. 3), channel health, the detector's distance, the free energy.

use std::path::Path;

use plotters::prelude::*;

use super::{ReportError, write_atomic};
use crate::scenario::TrajectoryRecorder;

/// Plots keep at most this many points per series (stride decimation).
const MAX_POINTS: usize = 2000;

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn stride(len: usize) -> usize {
    len.div_ceil(MAX_POINTS).max(1)
}

/// Draws into a string and writes it atomically.
fn render(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, plotters::coord::Shift>) -> Result<(), String>,
) -> Result<(), ReportError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(path, e))?;
        draw(&root).map_err(|message| ReportError::Plot {
            path: path.to_path_buf(),
            message,
        })?;
        root.present().map_err(|e| plot_error(path, e))?;
    }
    write_atomic(path, svg.as_bytes())
}

fn plot_error(path: &Path, e: impl std::fmt::Display) -> ReportError {
    ReportError::Plot {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn range_of<'a>(series: impl Iterator<Item = &'a Vec<f64>>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for s in series {
        for v in s.iter().filter(|v| v.is_finite()) {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    (lo - pad, hi + pad)
}

/// One line chart: named series against t, optional vertical marker (the fault), optional log y.
#[allow(clippy::too_many_arguments)]
fn chart(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    title: &str,
    y_label: &str,
    t: &[f64],
    series: &[(String, Vec<f64>, usize, bool)],
    marker: Option<f64>,
    log_y: Option<(f64, f64)>,
    hline: Option<f64>,
) -> Result<(), String> {
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let t_max = t.last().copied().unwrap_or(1.0).max(1e-9);
    let step = stride(t.len());
    let points = |v: &[f64]| -> Vec<(f64, f64)> {
        t.iter()
            .zip(v)
            .step_by(step)
            .filter(|(_, y)| y.is_finite())
            .map(|(x, y)| (*x, *y))
            .collect()
    };
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(title, ("sans-serif", 18))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64);
    let log = log_y.is_some();
    let y_format = move |v: &f64| {
        if log {
            format!("{v:.0e}")
        } else {
            format!("{v:.3}")
        }
    };
    macro_rules! draw_all {
        ($chart:expr, $lo:expr, $hi:expr) => {{
            let chart = &mut $chart;
            chart
                .configure_mesh()
                .x_desc("t (s)")
                .y_desc(y_label)
                .y_label_formatter(&y_format)
                .light_line_style(WHITE)
                .draw()
                .map_err(|x| e(&x))?;
            for (i, (name, values, colour, dashed)) in series.iter().enumerate() {
                let colour = PALETTE[*colour % PALETTE.len()];
                let style = if *dashed {
                    colour.stroke_width(1)
                } else {
                    colour.stroke_width(2)
                };
                let pts = points(values);
                let drawn = if *dashed {
                    chart
                        .draw_series(DashedLineSeries::new(pts, 6, 4, style))
                        .map_err(|x| e(&x))?
                } else {
                    chart
                        .draw_series(LineSeries::new(pts, style))
                        .map_err(|x| e(&x))?
                };
                let _ = i;
                drawn.label(name.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            }
            // A fault after the plotted span (a replayed log shorter than its scenario) is not
            // drawn: its coordinate would lie far off the canvas.
            if let Some(tf) = marker.filter(|tf| (0.0..=t_max).contains(tf)) {
                chart
                    .draw_series(DashedLineSeries::new(
                        vec![(tf, $lo), (tf, $hi)],
                        8,
                        4,
                        BLACK.stroke_width(1),
                    ))
                    .map_err(|x| e(&x))?
                    .label("fault")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK));
            }
            if let Some(h) = hline {
                chart
                    .draw_series(LineSeries::new(
                        vec![(0.0, h), (t_max, h)],
                        BLACK.mix(0.5).stroke_width(1),
                    ))
                    .map_err(|x| e(&x))?
                    .label("threshold")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.mix(0.5)));
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK.mix(0.3))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(|x| e(&x))?;
        }};
    }
    match log_y {
        Some((lo, hi)) => {
            let mut c = builder
                .build_cartesian_2d(0.0..t_max, (lo..hi).log_scale())
                .map_err(|x| e(&x))?;
            draw_all!(c, lo, hi);
        }
        None => {
            let (lo, hi) = range_of(series.iter().map(|s| &s.1));
            let mut c = builder
                .build_cartesian_2d(0.0..t_max, lo..hi)
                .map_err(|x| e(&x))?;
            draw_all!(c, lo, hi);
        }
    }
    Ok(())
}

/// Joint angles: truth, belief and target per joint, the fault marked (the paper's Fig. 3).
pub fn joint_angles(
    path: &Path,
    rec: &TrajectoryRecorder,
    fault: Option<f64>,
) -> Result<(), ReportError> {
    let n = rec.n_joints();
    let t = rec.series("t").unwrap_or_default();
    render(path, (900, 260 * n as u32), |root| {
        let areas = root.split_evenly((n, 1));
        for (i, area) in areas.iter().enumerate() {
            let j = i + 1;
            let get = |name: String| rec.series(&name).unwrap_or_default();
            let series = vec![
                (format!("q{j} (truth)"), get(format!("q{j}")), 0, false),
                (format!("mu{j} (belief)"), get(format!("mu{j}")), 1, true),
                (format!("target{j}"), get(format!("target{j}")), 2, true),
            ];
            chart(
                area,
                &format!("joint {j}"),
                "angle (rad)",
                &t,
                &series,
                fault,
                None,
                None,
            )?;
        }
        Ok(())
    })
}

/// Every channel's health (omega / nominal) over time, log scale.
pub fn health(
    path: &Path,
    rec: &TrajectoryRecorder,
    fault: Option<f64>,
) -> Result<(), ReportError> {
    let t = rec.series("t").unwrap_or_default();
    let series: Vec<(String, Vec<f64>, usize, bool)> = rec
        .header
        .iter()
        .filter_map(|h| h.strip_prefix("health_"))
        .enumerate()
        .map(|(i, name)| {
            let v = rec
                .series(&format!("health_{name}"))
                .unwrap_or_default()
                .into_iter()
                .map(|x| x.max(1e-7))
                .collect();
            (name.to_string(), v, i, false)
        })
        .collect();
    render(path, (900, 420), |root| {
        chart(
            root,
            "channel health (precision / nominal)",
            "health",
            &t,
            &series,
            fault,
            Some((1e-7, 2.0)),
            None,
        )
    })
}

/// The detector's normalised Mahalanobis distance per group (1 = the alarm threshold).
pub fn detector(
    path: &Path,
    rec: &TrajectoryRecorder,
    fault: Option<f64>,
) -> Result<(), ReportError> {
    let t = rec.series("t").unwrap_or_default();
    let groups: Vec<&str> = rec
        .header
        .iter()
        .filter_map(|h| h.strip_prefix("d_"))
        .collect();
    let series: Vec<(String, Vec<f64>, usize, bool)> = groups
        .iter()
        .enumerate()
        .map(|(i, g)| {
            let v: Vec<f64> = rec
                .series(&format!("d_{g}"))
                .unwrap_or_default()
                .into_iter()
                .map(|x| if x.is_finite() { x.max(1e-4) } else { x })
                .collect();
            (g.to_string(), v, i, false)
        })
        .collect();
    let hi = series
        .iter()
        .flat_map(|s| s.1.iter())
        .filter(|v| v.is_finite())
        .fold(10.0f64, |a, b| a.max(*b))
        * 2.0;
    let ran = series.iter().any(|s| s.1.iter().any(|v| v.is_finite()));
    let title = if ran {
        "detector: d_M / threshold per sensor group"
    } else {
        "detector: not run by this method (pl-detect and deterministic use it)"
    };
    render(path, (900, 420), |root| {
        chart(
            root,
            title,
            "normalised distance",
            &t,
            &series,
            fault,
            Some((1e-4, hi)),
            Some(1.0),
        )
    })
}

/// The free energy over time.
pub fn free_energy(
    path: &Path,
    rec: &TrajectoryRecorder,
    fault: Option<f64>,
) -> Result<(), ReportError> {
    let t = rec.series("t").unwrap_or_default();
    let series = vec![(
        "F".to_string(),
        rec.series("F").unwrap_or_default(),
        0,
        false,
    )];
    render(path, (900, 360), |root| {
        chart(
            root,
            "free energy",
            "F (nats)",
            &t,
            &series,
            fault,
            None,
            None,
        )
    })
}
