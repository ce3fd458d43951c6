//! `prism bench budget`: the quick start at several multiples of its step counts (a benchmark
//! that takes hours at 16x, not a test), to see whether the NVS decoder's gain over its own
//! 3DGS render `I_gs` grows with the budget. Each multiple is a quick start in its own folder
//! (`1x/`, `4x/`, ...) with a [`POINT_FILE`] once done (kept on the next run when its
//! [`Provenance`] is the point's, refused when not; an unfinished one continues from its runs'
//! last checkpoints, as [`quickstart`] does); the table
//! ([`BUDGET_TABLE`]) and a plot of PSNR against the teacher's steps ([`BUDGET_PLOT`]: NVS and
//! `I_gs` of teacher and student, and copy-source, overall and in the disoccluded region) are
//! rewritten after each multiple.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use image::RgbImage;
use plotters::coord::Shift;
use plotters::prelude::*;
use prism_core::files::{write_bytes, write_json};
use prism_losses::ImageScores;
use serde::{Deserialize, Serialize};

use crate::ablate::{AblationRow, RowResult, mean_step_seconds, read_finished};
use crate::error::{Result, TrainError};
use crate::images::save_png;
use crate::plot::{FONT, draw_legend_box, register_font};
use crate::provenance::{Provenance, dataset_digest_of};
use crate::quickstart::{PipelineOptions, QuickstartModel, QuickstartPlan, StudentJob, quickstart};

/// A finished multiple's result, in its folder.
pub const POINT_FILE: &str = "point.json";
/// The table (Markdown), in the benchmark's folder.
pub const BUDGET_TABLE: &str = "budget.md";
/// The plot (PNG), in the benchmark's folder.
pub const BUDGET_PLOT: &str = "budget.png";
/// Width and height of the plot, pixels.
const PLOT_SIZE: (u32, u32) = (1280, 900);

/// The teacher and the student of the quick start at one multiple of its steps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BudgetPoint {
    /// The multiple of the quick start's step counts.
    pub multiple: usize,
    /// The teacher (its `seconds_per_step` is the run's mean).
    pub teacher: RowResult,
    /// The student.
    pub student: RowResult,
    /// What the point was made from; a finished point is kept only for the same.
    #[serde(default)]
    pub provenance: Provenance,
}

/// Runs the quick start `plan` at each of `multiples` of its step counts into
/// `options.out/<m>x/` (multiples already done are kept) and writes the table and the plot;
/// returns the points and the table's path.
///
/// # Errors
/// Any error of a quick start, or a file that cannot be read or written.
pub fn budget_curve(
    plan: &QuickstartPlan,
    multiples: &[usize],
    options: &PipelineOptions,
    student_job: StudentJob<'_>,
) -> Result<(Vec<BudgetPoint>, PathBuf)> {
    let mut points = Vec::new();
    let table = options.out.join(BUDGET_TABLE);
    let dataset = dataset_digest_of(&options.data)?;
    for &multiple in multiples {
        let dir = options.out.join(format!("{multiple}x"));
        let file = dir.join(POINT_FILE);
        let scaled = QuickstartPlan {
            teacher_steps: plan.teacher_steps * multiple,
            student_steps: plan.student_steps * multiple,
            ..plan.clone()
        };
        let point_plan = serde_json::json!({
            "multiple": multiple,
            "teacher_steps": scaled.teacher_steps,
            "student_steps": scaled.student_steps,
            "eval_views": scaled.eval_views,
        });
        let provenance = Provenance::new(&plan.config, &dataset, &point_plan);
        let point = if file.is_file() {
            let point: BudgetPoint = read_finished(&file, "a point of a budget curve")?;
            provenance.check(&point.provenance, &file)?;
            point
        } else {
            let run = PipelineOptions {
                out: dir.clone(),
                ..options.clone()
            };
            let report = quickstart(&scaled, &run, student_job)?;
            let row = |row: AblationRow, m: &QuickstartModel| -> Result<RowResult> {
                let seconds = mean_step_seconds(&m.run)?;
                let p = provenance.clone();
                Ok(RowResult::of(row, m.steps, seconds, &m.evaluation, p))
            };
            let point = BudgetPoint {
                multiple,
                teacher: row(AblationRow::Teacher, &report.teacher)?,
                student: row(AblationRow::Progressive, &report.student)?,
                provenance: provenance.clone(),
            };
            write_json(&file, &point).map_err(|e| TrainError::io(&file, e))?;
            point
        };
        points.push(point);
        write_budget(plan, &points, &options.out)?;
    }
    Ok((points, table))
}

/// Writes the table and the plot of `points` into `out`.
fn write_budget(plan: &QuickstartPlan, points: &[BudgetPoint], out: &Path) -> Result<()> {
    let table = out.join(BUDGET_TABLE);
    write_bytes(&table, budget_markdown(plan, points).as_bytes())
        .map_err(|e| TrainError::io(&table, e))?;
    let plot = out.join(BUDGET_PLOT);
    let image = draw_budget(plan, points).map_err(|message| TrainError::Plot {
        path: plot.clone(),
        message,
    })?;
    save_png(&plot, &image)
}

/// The table: per multiple and model, PSNR of NVS, `I_gs` and copy-source, overall and in the
/// disoccluded region, and NVS minus `I_gs`.
pub fn budget_markdown(plan: &QuickstartPlan, points: &[BudgetPoint]) -> String {
    let mut out = format!(
        "# Budget curve of the {} quick start ({} teacher + {} student steps at 1x, {} views per \
         held-out person)\n\nPSNR (dB) overall / in the disoccluded region.\n\n| budget | model | \
         steps | NVS | I_gs | copy source | NVS - I_gs | LPIPS NVS / I_gs / copy |\n|---|---|---:|\
         ---:|---:|---:|---:|---:|\n",
        plan.name, plan.teacher_steps, plan.student_steps, plan.eval_views
    );
    let pair = |s: Option<ImageScores>, d: Option<ImageScores>| {
        let f = |v: Option<ImageScores>| v.map_or("-".into(), |v| format!("{:.2}", v.psnr));
        format!("{} / {}", f(s), f(d))
    };
    let gain = |a: Option<ImageScores>, b: Option<ImageScores>| match (a, b) {
        (Some(a), Some(b)) => format!("{:+.2}", a.psnr - b.psnr),
        _ => "-".into(),
    };
    let lpips = |s: Option<ImageScores>| s.map_or("-".into(), |s| format!("{:.4}", s.lpips));
    for p in points {
        for r in [&p.teacher, &p.student] {
            let _ = writeln!(
                out,
                "| {}x | {} | {} | {} | {} | {} | {} / {} | {} / {} / {} |",
                p.multiple,
                r.row,
                r.steps,
                pair(Some(r.model), r.model_disoccluded),
                pair(r.gs, r.gs_disoccluded),
                pair(Some(r.copy_source), r.copy_source_disoccluded),
                gain(Some(r.model), r.gs),
                gain(r.model_disoccluded, r.gs_disoccluded),
                lpips(Some(r.model)),
                lpips(r.gs),
                lpips(Some(r.copy_source)),
            );
        }
    }
    out
}

/// One line of the plot: its name, colour, dash and the value it reads from a point.
struct Line {
    name: &'static str,
    colour: RGBColor,
    dashed: bool,
    value: fn(&BudgetPoint, bool) -> Option<f64>,
}

/// The scores of a row, overall or in the disoccluded region.
fn scores(r: &RowResult, region: bool, gs: bool) -> Option<ImageScores> {
    match (gs, region) {
        (false, false) => Some(r.model),
        (false, true) => r.model_disoccluded,
        (true, false) => r.gs,
        (true, true) => r.gs_disoccluded,
    }
}

const LINES: [Line; 5] = [
    Line {
        name: "teacher NVS",
        colour: RGBColor(31, 119, 180),
        dashed: false,
        value: |p, region| scores(&p.teacher, region, false).map(|s| s.psnr),
    },
    Line {
        name: "teacher I_gs",
        colour: RGBColor(255, 127, 14),
        dashed: false,
        value: |p, region| scores(&p.teacher, region, true).map(|s| s.psnr),
    },
    Line {
        name: "student NVS",
        colour: RGBColor(44, 160, 44),
        dashed: false,
        value: |p, region| scores(&p.student, region, false).map(|s| s.psnr),
    },
    Line {
        name: "student I_gs",
        colour: RGBColor(148, 103, 189),
        dashed: false,
        value: |p, region| scores(&p.student, region, true).map(|s| s.psnr),
    },
    Line {
        name: "copy source",
        colour: RGBColor(214, 39, 40),
        dashed: true,
        value: |p, region| {
            if region {
                p.teacher.copy_source_disoccluded.map(|s| s.psnr)
            } else {
                Some(p.teacher.copy_source.psnr)
            }
        },
    },
];

/// Two panels, PSNR overall and in the disoccluded region, against the teacher's steps.
fn draw_budget(
    plan: &QuickstartPlan,
    points: &[BudgetPoint],
) -> std::result::Result<RgbImage, String> {
    register_font();
    let (w, h) = PLOT_SIZE;
    let mut buffer = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let title = format!("budget curve of the {} quick start", plan.name);
        let root = root.titled(&title, (FONT, 26)).map_err(|e| e.to_string())?;
        let panels = root.split_evenly((1, 2));
        for (area, region) in panels.iter().zip([false, true]) {
            draw_panel(area, points, region)?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    RgbImage::from_raw(w, h, buffer).ok_or_else(|| "the plot buffer has the wrong size".into())
}

/// One panel: a line per [`LINES`] entry against log2 of the teacher steps.
fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    points: &[BudgetPoint],
    region: bool,
) -> std::result::Result<(), String> {
    let series: Vec<Vec<(f64, f64)>> = LINES
        .iter()
        .map(|line| {
            points
                .iter()
                .filter_map(|p| {
                    let v = (line.value)(p, region)?;
                    v.is_finite()
                        .then_some(((p.teacher.steps.max(1) as f64).log2(), v))
                })
                .collect()
        })
        .collect();
    let all = || series.iter().flatten();
    let (x0, x1) = all().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &(x, _)| {
        (a.min(x), b.max(x))
    });
    let (y0, y1) = all().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &(_, y)| {
        (a.min(y), b.max(y))
    });
    if !x0.is_finite() {
        return Ok(());
    }
    let span = (y1 - y0).max(0.5);
    let caption = if region {
        "PSNR in the disoccluded region"
    } else {
        "PSNR overall"
    };
    let mut chart = ChartBuilder::on(area)
        .margin(14)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .caption(caption, (FONT, 20))
        .build_cartesian_2d(x0 - 0.5..x1 + 0.5, y0 - 0.15 * span..y1 + 0.5 * span)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("teacher steps, log scale (student: half)")
        .y_desc("PSNR (dB)")
        .x_labels(8)
        .x_label_formatter(&|x| format!("{:.0}", x.exp2()))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()
        .map_err(|e| e.to_string())?;
    for (line, points) in LINES.iter().zip(&series) {
        let style = line.colour.stroke_width(2);
        let drawn = if line.dashed {
            chart.draw_series(DashedLineSeries::new(points.iter().copied(), 10, 6, style))
        } else {
            chart.draw_series(LineSeries::new(points.iter().copied(), style))
        };
        drawn
            .map_err(|e| e.to_string())?
            .label(line.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        chart
            .draw_series(
                points
                    .iter()
                    .map(|&p| Circle::new(p, 4, line.colour.filled())),
            )
            .map_err(|e| e.to_string())?;
    }
    draw_legend_box(&mut chart, SeriesLabelPosition::UpperLeft)
}
