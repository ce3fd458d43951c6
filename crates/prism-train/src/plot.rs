//! Training curves: a PNG of a run's `metrics.jsonl` (see [`crate::log`]), written into the
//! run folder as [`PLOT_FILE`] at each validation and when the run ends.
//!
//! Four panels: the loss terms against the step (log scale when every value is positive,
//! linear otherwise; the total `loss` in black), and validation PSNR, SSIM and LPIPS against
//! the step, each with the "copy the source view" baseline as a dashed horizontal line: the
//! score a model must beat to have learnt anything about other viewpoints.
//!
//! Text is drawn with a font embedded in the binary (Ubuntu Light, from the
//! `epaint_default_fonts` crate, through plotters' `ab_glyph` text renderer), so a plot is the
//! same on a machine without any system font.

use std::path::{Path, PathBuf};
use std::sync::Once;

use image::RgbImage;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use serde_json::Value;

use crate::error::{Result, TrainError};
use crate::images::save_png;
use crate::log::{METRICS_FILE, read_metrics};

/// File name of the training curves in a run folder (beside `metrics.jsonl`).
pub const PLOT_FILE: &str = "metrics.png";
/// Width and height of the plot, pixels.
pub const PLOT_SIZE: (u32, u32) = (1280, 880);
/// Points drawn per curve at most: longer curves are averaged over runs of consecutive steps,
/// so that a plot of a long run stays quick to draw and readable.
pub const MAX_POINTS: usize = 1000;

/// The font family every text of the plot uses (registered once with the embedded font).
pub(crate) const FONT: &str = "sans-serif";
/// The keys of a step line that are not loss terms.
const NOT_TERMS: [&str; 5] = ["step", "lr", "lr_heads", "grad_norm", "seconds"];
/// Colours of the loss terms after the total (Tableau 10).
const COLOURS: [RGBColor; 9] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];
/// Colour of the validation curves.
const MODEL_COLOUR: RGBColor = RGBColor(31, 119, 180);
/// Colour of the copy-the-source baseline.
const BASELINE_COLOUR: RGBColor = RGBColor(214, 39, 40);

/// Decades of the log scale of the loss terms below the largest value, at most.
const LOG_DECADES: i32 = 6;
/// Width of the legend beside the loss terms, pixels.
const LOSS_LEGEND_WIDTH: u32 = 110;

/// One validation metric of the plot: its panel title, its key in `metrics.jsonl` and the key
/// of its copy-the-source baseline.
struct Metric {
    title: &'static str,
    axis: &'static str,
    key: &'static str,
    baseline_key: &'static str,
    /// The smallest span of the y axis.
    min_span: f64,
}

const METRICS: [Metric; 3] = [
    Metric {
        title: "validation PSNR (higher is better)",
        axis: "PSNR (dB)",
        key: "val_psnr",
        baseline_key: "copy_source_psnr",
        min_span: 1.0,
    },
    Metric {
        title: "validation SSIM (higher is better)",
        axis: "SSIM",
        key: "val_ssim",
        baseline_key: "copy_source_ssim",
        min_span: 0.02,
    },
    Metric {
        title: "validation LPIPS (lower is better)",
        axis: "LPIPS",
        key: "val_lpips",
        baseline_key: "copy_source_lpips",
        min_span: 0.02,
    },
];

/// The curves of a run, read from its `metrics.jsonl` lines.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainingCurves {
    /// Each loss term's `(step, value)` over the steps taken (skipped steps and non-finite
    /// values left out), in the order first logged: `loss` (the total) first.
    pub losses: Vec<(String, Vec<(f64, f64)>)>,
    /// The validations' `(step, value)` of PSNR, SSIM and LPIPS (non-finite values left out).
    pub validation: [Vec<(f64, f64)>; 3],
    /// The copy-the-source baseline's PSNR, SSIM and LPIPS (`None` when not logged or not
    /// finite).
    pub baseline: [Option<f64>; 3],
    /// The last step logged.
    pub last_step: usize,
}

impl TrainingCurves {
    /// The curves of the objects of a metrics log, in order.
    pub fn from_lines(lines: &[Value]) -> Self {
        let mut curves = Self::default();
        for line in lines {
            let Some(fields) = line.as_object() else {
                continue;
            };
            let Some(step) = fields.get("step").and_then(Value::as_u64) else {
                continue;
            };
            curves.last_step = curves.last_step.max(step as usize);
            let x = step as f64;
            let skipped = fields.get("skipped").and_then(Value::as_bool) == Some(true);
            if fields.contains_key("loss") && !skipped {
                let mut terms: Vec<(&String, f64)> = fields
                    .iter()
                    .filter(|(k, _)| !NOT_TERMS.contains(&k.as_str()))
                    .filter_map(|(k, v)| Some((k, v.as_f64()?)))
                    .filter(|(_, v)| v.is_finite())
                    .collect();
                // The total first, then the terms.
                terms.sort_by_key(|(k, _)| k.as_str() != "loss");
                for (name, value) in terms {
                    match curves.losses.iter_mut().find(|(n, _)| n == name) {
                        Some((_, points)) => points.push((x, value)),
                        None => curves.losses.push((name.clone(), vec![(x, value)])),
                    }
                }
            }
            for (k, metric) in METRICS.iter().enumerate() {
                if let Some(v) = fields.get(metric.key).and_then(Value::as_f64)
                    && v.is_finite()
                {
                    curves.validation[k].push((x, v));
                }
                if let Some(v) = fields.get(metric.baseline_key).and_then(Value::as_f64)
                    && v.is_finite()
                {
                    curves.baseline[k] = Some(v);
                }
            }
        }
        curves
    }

    /// The curves of the metrics log at `path`.
    ///
    /// # Errors
    /// When the file cannot be read.
    pub fn read(path: &Path) -> Result<Self> {
        Ok(Self::from_lines(&read_metrics(path)?))
    }
}

/// Draws the curves of `metrics` (a `metrics.jsonl`) into the PNG `out` (written atomically),
/// [`PLOT_SIZE`], headed by `title`.
///
/// # Errors
/// When the log cannot be read, or the PNG cannot be drawn or written.
pub fn plot_metrics(metrics: &Path, out: &Path, title: &str) -> Result<()> {
    let curves = TrainingCurves::read(metrics)?;
    let image = draw_curves(&curves, title).map_err(|message| TrainError::Plot {
        path: out.to_path_buf(),
        message,
    })?;
    save_png(out, &image)
}

/// Draws a run folder's `metrics.jsonl` into `run/`[`PLOT_FILE`]; returns its path.
///
/// # Errors
/// As [`plot_metrics`].
pub fn plot_run(run: &Path) -> Result<PathBuf> {
    let out = run.join(PLOT_FILE);
    let name = run
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| run.display().to_string());
    plot_metrics(
        &run.join(METRICS_FILE),
        &out,
        &format!("training curves of {name}"),
    )?;
    Ok(out)
}

/// Registers the embedded font as the plot's font family (once per process).
pub(crate) fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            epaint_default_fonts::UBUNTU_LIGHT,
        )
        .is_err()
        {
            unreachable!("the embedded font parses");
        }
    });
}

/// Draws the four panels of `curves` under `title` into an image of [`PLOT_SIZE`].
///
/// # Errors
/// A message when plotters cannot draw (e.g. the font is unusable).
pub fn draw_curves(curves: &TrainingCurves, title: &str) -> std::result::Result<RgbImage, String> {
    register_font();
    let (w, h) = PLOT_SIZE;
    let mut buffer = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let root = root.titled(title, (FONT, 26)).map_err(|e| e.to_string())?;
        let panels = root.split_evenly((2, 2));
        let x_max = curves.last_step.max(1) as f64;
        losses_panel(&panels[0], &curves.losses, x_max)?;
        for (k, metric) in METRICS.iter().enumerate() {
            validation_panel(
                &panels[k + 1],
                metric,
                &curves.validation[k],
                curves.baseline[k],
                x_max,
            )?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    RgbImage::from_raw(w, h, buffer).ok_or_else(|| "the plot buffer has the wrong size".into())
}

type Panel<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// The loss terms against the step.
fn losses_panel(
    area: &Panel<'_>,
    losses: &[(String, Vec<(f64, f64)>)],
    x_max: f64,
) -> std::result::Result<(), String> {
    let values = || losses.iter().flat_map(|(_, p)| p.iter().map(|&(_, v)| v));
    let (lo, hi) = values().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !lo.is_finite() {
        return empty_panel(area, "loss terms", "no training step logged yet");
    }
    // A log scale unless a term is negative, spanning at most LOG_DECADES below the largest
    // value: smaller values (a term that starts at 0, e.g. L_distill) are drawn at its floor.
    let log = lo >= 0.0 && hi > 0.0;
    let smallest = values().filter(|&v| v > 0.0).fold(f64::INFINITY, f64::min);
    let floor = smallest.max(hi * 10f64.powi(-LOG_DECADES));
    let series: Vec<LossLine> = losses
        .iter()
        .zip(loss_styles(losses))
        .map(|((name, points), style)| LossLine {
            name: name.clone(),
            points: thin(points)
                .into_iter()
                .map(|(x, v)| (x, if log { v.max(floor) } else { v }))
                .collect(),
            style,
        })
        .collect();
    let (w, _) = area.dim_in_pixel();
    let (plot, legend) = area.split_horizontally(w.saturating_sub(LOSS_LEGEND_WIDTH));
    draw_legend(&legend, &series)?;
    let builder = || {
        let mut b = ChartBuilder::on(&plot);
        b.margin(12).x_label_area_size(40).y_label_area_size(70);
        b
    };
    if log {
        let caption = if lo < floor {
            format!("loss terms (log scale; below {} drawn at it)", tick(floor))
        } else {
            "loss terms (log scale)".to_string()
        };
        let chart = builder()
            .caption(caption, (FONT, 20))
            .build_cartesian_2d(0.0..x_max, (floor * 0.8..hi * 1.25).log_scale())
            .map_err(|e| e.to_string())?;
        draw_lines(chart, &series)
    } else {
        let (lo, hi) = padded(lo, hi, 1e-3);
        let chart = builder()
            .caption("loss terms (linear: some are negative)", (FONT, 20))
            .build_cartesian_2d(0.0..x_max, lo..hi)
            .map_err(|e| e.to_string())?;
        draw_lines(chart, &series)
    }
}

/// A loss curve as drawn: its name, its (thinned) points and its line style.
struct LossLine {
    name: String,
    points: Vec<(f64, f64)>,
    style: ShapeStyle,
}

/// The line style of each loss term: the total thick and black, the terms in [`COLOURS`].
fn loss_styles(losses: &[(String, Vec<(f64, f64)>)]) -> Vec<ShapeStyle> {
    let mut colours = COLOURS.iter().cycle();
    losses
        .iter()
        .map(|(name, _)| {
            if name == "loss" {
                BLACK.stroke_width(2)
            } else {
                colours.next().expect("cycle").stroke_width(1)
            }
        })
        .collect()
}

/// The legend of the loss terms, one line each, in its own strip beside the chart (so that it
/// never hides a curve).
fn draw_legend(area: &Panel<'_>, series: &[LossLine]) -> std::result::Result<(), String> {
    let style = TextStyle::from((FONT, 14).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    for (i, line) in series.iter().enumerate() {
        let y = 60 + 22 * i as i32;
        area.draw(&PathElement::new(vec![(4, y), (26, y)], line.style))
            .map_err(|e| e.to_string())?;
        area.draw_text(&line.name, &style, (32, y))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// The mesh and the loss curves.
fn draw_lines<'a, Y>(
    mut chart: ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, Y>>,
    series: &[LossLine],
) -> std::result::Result<(), String>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc("loss")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| tick(*y))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()
        .map_err(|e| e.to_string())?;
    for line in series {
        chart
            .draw_series(LineSeries::new(line.points.iter().copied(), line.style))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// One validation metric against the step, with the copy-the-source baseline.
fn validation_panel(
    area: &Panel<'_>,
    metric: &Metric,
    points: &[(f64, f64)],
    baseline: Option<f64>,
    x_max: f64,
) -> std::result::Result<(), String> {
    let values = points.iter().map(|&(_, v)| v).chain(baseline);
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !lo.is_finite() {
        let why = if metric.key == "val_lpips" {
            "not measured (LPIPS needs images of at least 31 px)"
        } else {
            "no validation logged yet"
        };
        return empty_panel(area, metric.title, why);
    }
    let (lo, hi) = padded(lo, hi, metric.min_span);
    // Room above the curves for the legend.
    let hi = hi + 0.3 * (hi - lo);
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .caption(metric.title, (FONT, 20))
        .build_cartesian_2d(0.0..x_max, lo..hi)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc(metric.axis)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()
        .map_err(|e| e.to_string())?;
    let model = MODEL_COLOUR.stroke_width(2);
    chart
        .draw_series(LineSeries::new(points.iter().copied(), model))
        .map_err(|e| e.to_string())?
        .label("model (NVS decoder)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], model));
    chart
        .draw_series(
            points
                .iter()
                .map(|&p| Circle::new(p, 3, MODEL_COLOUR.filled())),
        )
        .map_err(|e| e.to_string())?;
    if let Some(b) = baseline {
        let style = BASELINE_COLOUR.stroke_width(2);
        chart
            .draw_series(DashedLineSeries::new([(0.0, b), (x_max, b)], 10, 6, style))
            .map_err(|e| e.to_string())?
            .label(format!("copy source (view 0): {b:.4}"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    draw_legend_box(&mut chart, SeriesLabelPosition::UpperRight)
}

/// The legend of a chart's labelled series, in a framed, half-transparent box at `position`
/// (every plot of the crate draws its legends this way).
pub(crate) fn draw_legend_box<'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, CT>,
    position: SeriesLabelPosition,
) -> std::result::Result<(), String> {
    chart
        .configure_series_labels()
        .label_font((FONT, 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(position)
        .draw()
        .map_err(|e| e.to_string())
}

/// A panel with a caption and a note instead of a chart.
fn empty_panel(area: &Panel<'_>, title: &str, note: &str) -> std::result::Result<(), String> {
    let (w, h) = area.dim_in_pixel();
    let style = TextStyle::from((FONT, 18).into_font()).pos(Pos::new(HPos::Center, VPos::Center));
    area.draw_text(title, &style, (w as i32 / 2, 24))
        .map_err(|e| e.to_string())?;
    area.draw_text(note, &style, (w as i32 / 2, h as i32 / 2))
        .map_err(|e| e.to_string())
}

/// A tick label: up to 4 significant digits, scientific notation outside [1e-3, 1e4).
fn tick(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        return "0".into();
    }
    if !(1e-3..1e4).contains(&a) {
        return format!("{v:.0e}");
    }
    let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
    let text = format!("{v:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// `[lo, hi]` widened by a tenth of its span on each side, the span at least `min_span`.
fn padded(lo: f64, hi: f64, min_span: f64) -> (f64, f64) {
    let span = (hi - lo).max(min_span);
    let mid = (lo + hi) / 2.0;
    (mid - 0.6 * span, mid + 0.6 * span)
}

/// At most [`MAX_POINTS`] points: runs of consecutive points averaged (step and value).
fn thin(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    if points.len() <= MAX_POINTS {
        return points.to_vec();
    }
    let run = points.len().div_ceil(MAX_POINTS);
    points
        .chunks(run)
        .map(|c| {
            let n = c.len() as f64;
            (
                c.iter().map(|p| p.0).sum::<f64>() / n,
                c.iter().map(|p| p.1).sum::<f64>() / n,
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::log::MetricsLog;
    use serde_json::json;

    /// A synthetic run's log: the baseline, validations at steps 0, 10 and 20 (LPIPS `null`
    /// at step 0), 20 steps with two terms, one skipped step and a distillation event.
    fn synthetic_log(dir: &Path) {
        let mut log = MetricsLog::open(dir, None).unwrap();
        let lines = [
            json!({"step": 0, "copy_source_psnr": 14.0, "copy_source_ssim": 0.6,
                   "copy_source_lpips": 0.3}),
            json!({"step": 0, "val_psnr": 8.0, "val_ssim": 0.2, "val_lpips": null,
                   "samples": "samples/step-00000000.png"}),
        ];
        for line in &lines {
            log.write(line).unwrap();
        }
        for step in 1..=20 {
            let s = step as f64;
            let line = if step == 7 {
                json!({"step": step, "skipped": true, "reason": "non-finite loss",
                       "loss": null, "grad_norm": 1.0, "lr": 1e-3})
            } else {
                json!({"step": step, "loss": 2.0 / s, "nvs_mse": 1.0 / s, "pts": 1.0 / s,
                       "lr": 1e-3, "lr_heads": 1e-3, "grad_norm": 0.5, "seconds": 0.1})
            };
            log.write(&line).unwrap();
            if step == 12 {
                log.write(&json!({"step": 12, "switched": [1, 4]})).unwrap();
            }
            if step % 10 == 0 {
                log.write(&json!({"step": step, "val_psnr": 10.0 + s / 2.0,
                                  "val_ssim": 0.5, "val_lpips": 0.5 - s / 80.0,
                                  "samples": "x.png"}))
                    .unwrap();
            }
        }
    }

    #[test]
    fn curves_hold_the_terms_validations_and_baseline() {
        let dir = tempfile::tempdir().unwrap();
        synthetic_log(dir.path());
        let curves = TrainingCurves::read(&dir.path().join(METRICS_FILE)).unwrap();
        let names: Vec<&str> = curves.losses.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["loss", "nvs_mse", "pts"]);
        // 19 steps taken (step 7 skipped), each term at every one.
        let loss = &curves.losses[0].1;
        assert_eq!(loss.len(), 19);
        assert!(!loss.iter().any(|&(x, _)| x == 7.0));
        assert_eq!(loss[1], (2.0, 1.0));
        assert_eq!(
            curves.validation[0],
            vec![(0.0, 8.0), (10.0, 15.0), (20.0, 20.0)]
        );
        // The null LPIPS of step 0 is left out.
        assert_eq!(curves.validation[2], vec![(10.0, 0.375), (20.0, 0.25)]);
        assert_eq!(curves.baseline, [Some(14.0), Some(0.6), Some(0.3)]);
        assert_eq!(curves.last_step, 20);
    }

    #[test]
    fn the_plot_is_a_png_with_curves_and_baseline() {
        let dir = tempfile::tempdir().unwrap();
        synthetic_log(dir.path());
        let path = plot_run(dir.path()).unwrap();
        assert_eq!(path, dir.path().join(PLOT_FILE));
        let image = image::open(&path).unwrap().to_rgb8();
        assert_eq!((image.width(), image.height()), PLOT_SIZE);
        let count = |colour: RGBColor| {
            image
                .pixels()
                .filter(|p| p.0 == [colour.0, colour.1, colour.2])
                .count()
        };
        let white = count(WHITE);
        let total = (PLOT_SIZE.0 * PLOT_SIZE.1) as usize;
        // Mostly white, but with text, axes and curves drawn.
        assert!(white > total / 2 && white < total - 20_000, "{white}");
        // The baseline (dashed, in three panels) and the validation curves are there.
        assert!(count(BASELINE_COLOUR) > 300, "{}", count(BASELINE_COLOUR));
        assert!(count(MODEL_COLOUR) > 300, "{}", count(MODEL_COLOUR));
        // Text was rendered: anti-aliased glyphs leave grey pixels.
        let grey = image
            .pixels()
            .filter(|p| p.0[0] == p.0[1] && p.0[1] == p.0[2] && p.0[0] > 40 && p.0[0] < 215)
            .count();
        assert!(grey > 2_000, "{grey}");
    }

    #[test]
    fn an_empty_log_still_draws_and_long_curves_are_thinned() {
        let image = draw_curves(&TrainingCurves::default(), "nothing yet").unwrap();
        assert_eq!((image.width(), image.height()), PLOT_SIZE);
        let points: Vec<(f64, f64)> = (0..2500).map(|i| (i as f64, 1.0)).collect();
        let thinned = thin(&points);
        assert_eq!(thinned.len(), 834);
        assert_eq!(thinned[0], (1.0, 1.0));
        let ticks: Vec<String> = [0.0, 1e-7, 0.002, 0.1, 0.25, 1.0, 12.5, 300.0, 1e5]
            .into_iter()
            .map(tick)
            .collect();
        assert_eq!(
            ticks,
            [
                "0", "1e-7", "0.002", "0.1", "0.25", "1", "12.5", "300", "1e5"
            ]
        );
    }
}
