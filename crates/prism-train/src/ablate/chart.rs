//! The ablation's bar chart: per row, a bar for the model (NVS decoder) and one for its own
//! 3DGS render `I_gs`, with copy-the-source as a dashed line; three panels: PSNR overall,
//! PSNR in the disoccluded region and LPIPS overall.

use image::RgbImage;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use prism_losses::ImageScores;

use super::table::Pick;
use super::{Ablation, RowResult};
use crate::plot::{FONT, draw_legend_box, register_font};

/// Width and height of the chart, pixels.
pub const CHART_SIZE: (u32, u32) = (1280, 1200);

/// Colour of the model's bars.
const MODEL_COLOUR: RGBColor = RGBColor(31, 119, 180);
/// Colour of the `I_gs` bars.
const GS_COLOUR: RGBColor = RGBColor(255, 127, 14);
/// Colour of the copy-the-source line.
const BASELINE_COLOUR: RGBColor = RGBColor(214, 39, 40);
/// Width of one bar, in row spacings.
const BAR: f64 = 0.36;

/// One panel: its title, axis and the value it reads from a row's scores.
struct Panel {
    title: &'static str,
    axis: &'static str,
    pick: Pick,
    value: fn(&ImageScores) -> f64,
}

const PANELS: [Panel; 3] = [
    Panel {
        title: "PSNR overall (higher is better)",
        axis: "PSNR (dB)",
        pick: |r| (Some(r.model), r.gs, Some(r.copy_source)),
        value: |s| s.psnr,
    },
    Panel {
        title: "PSNR in the disoccluded region (higher is better)",
        axis: "PSNR (dB)",
        pick: |r| {
            (
                r.model_disoccluded,
                r.gs_disoccluded,
                r.copy_source_disoccluded,
            )
        },
        value: |s| s.psnr,
    },
    Panel {
        title: "LPIPS overall (lower is better)",
        axis: "LPIPS",
        pick: |r| (Some(r.model), r.gs, Some(r.copy_source)),
        value: |s| s.lpips,
    },
];

/// Draws the chart of `ablation` into an image of `CHART_SIZE`.
///
/// # Errors
/// A message when plotters cannot draw.
pub fn draw_ablation_chart(ablation: &Ablation) -> Result<RgbImage, String> {
    register_font();
    let (w, h) = CHART_SIZE;
    let mut buffer = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let title = format!(
            "ablation of the {} config: teacher rows {} steps, students {} steps",
            ablation.config, ablation.teacher_steps, ablation.student_steps
        );
        let root = root.titled(&title, (FONT, 26)).map_err(|e| e.to_string())?;
        for (area, panel) in root.split_evenly((PANELS.len(), 1)).iter().zip(&PANELS) {
            draw_panel(area, panel, &ablation.rows)?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    RgbImage::from_raw(w, h, buffer).ok_or_else(|| "the chart buffer has the wrong size".into())
}

/// One panel: the bars of every row and the baseline.
fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    panel: &Panel,
    rows: &[RowResult],
) -> Result<(), String> {
    let finite = |s: Option<ImageScores>| s.map(|s| (panel.value)(&s)).filter(|v| v.is_finite());
    let bars: Vec<[Option<f64>; 2]> = rows
        .iter()
        .map(|r| {
            let (model, gs, _) = (panel.pick)(r);
            [finite(model), finite(gs)]
        })
        .collect();
    let baseline = rows.first().and_then(|r| finite((panel.pick)(r).2));
    let values: Vec<f64> = bars
        .iter()
        .flatten()
        .flatten()
        .copied()
        .chain(baseline)
        .collect();
    if values.is_empty() {
        let style =
            TextStyle::from((FONT, 18).into_font()).pos(Pos::new(HPos::Center, VPos::Center));
        let (w, h) = area.dim_in_pixel();
        return area
            .draw_text(
                &format!("{}: not measured", panel.title),
                &style,
                (w as i32 / 2, h as i32 / 2),
            )
            .map_err(|e| e.to_string());
    }
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = (hi - lo).max(1e-3);
    // Bars start below the lowest value so that differences show; room above for the legend.
    let (y0, y1) = (lo - 0.3 * span, hi + 0.45 * span);
    let n = rows.len().max(1) as f64;
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .caption(panel.title, (FONT, 20))
        .build_cartesian_2d(-0.5..n - 0.5, y0..y1)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_desc(panel.axis)
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()
        .map_err(|e| e.to_string())?;
    for (k, (colour, name)) in [
        (MODEL_COLOUR, "model (NVS)"),
        (GS_COLOUR, "its I_gs (3DGS)"),
    ]
    .into_iter()
    .enumerate()
    {
        let offset = if k == 0 { -BAR } else { 0.0 };
        let rects = bars.iter().enumerate().filter_map(|(i, b)| {
            let x = i as f64 + offset;
            b[k].map(|v| Rectangle::new([(x, y0), (x + BAR, v)], colour.filled()))
        });
        chart
            .draw_series(rects)
            .map_err(|e| e.to_string())?
            .label(name)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.filled()));
    }
    if let Some(b) = baseline {
        let style = BASELINE_COLOUR.stroke_width(2);
        chart
            .draw_series(DashedLineSeries::new(
                [(-0.5, b), (n - 0.5, b)],
                10,
                6,
                style,
            ))
            .map_err(|e| e.to_string())?
            .label(format!("copy source (view 0): {b:.3}"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    draw_legend_box(&mut chart, SeriesLabelPosition::UpperRight)?;
    // The rows' names under their bars.
    let style = TextStyle::from((FONT, 14).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    for (i, row) in rows.iter().enumerate() {
        let (x, y) = chart.backend_coord(&(i as f64, y0));
        area.draw_text(&row.row, &style, (x, y + 6))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}
