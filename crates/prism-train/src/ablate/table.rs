//! The ablation's Markdown: one table of the overall scores and one of the scores in the
//! disoccluded region, each row beside its own `I_gs`, the copy-the-source baseline last.

use std::fmt::Write as _;

use prism_losses::{ImageScores, NO_VALUE, ScoreTable, score_cells};

use super::{Ablation, RowResult};

/// The ablation as Markdown: its budget, the overall table (with steps, seconds per step and
/// FPS) and the disoccluded-region table.
pub fn ablation_markdown(ablation: &Ablation) -> String {
    let mut out = format!(
        "# Ablation of the {} config\n\nTeacher rows {} steps, student rows {} steps (distilled \
         from the teacher row), {} target views per held-out person. Beside each row, the scores \
         of its own 3DGS render `I_gs`; the copy-the-source baseline is on the same views.\n\n",
        ablation.config, ablation.teacher_steps, ablation.student_steps, ablation.views
    );
    let overall = |r: &RowResult| (Some(r.model), r.gs, Some(r.copy_source));
    let region = |r: &RowResult| {
        (
            r.model_disoccluded,
            r.gs_disoccluded,
            r.copy_source_disoccluded,
        )
    };
    let _ = writeln!(out, "## Overall\n\n{}", table(ablation, overall, true));
    let _ = writeln!(
        out,
        "## In the disoccluded region (the target's foreground the source does not see)\n\n{}",
        table(ablation, region, false)
    );
    out
}

/// The model's, `I_gs`'s and copy-source's scores of a row.
pub(super) type Pick = fn(
    &RowResult,
) -> (
    Option<ImageScores>,
    Option<ImageScores>,
    Option<ImageScores>,
);

/// One table: a line per row, `I_gs`'s scores after the model's, copy-source last (the first
/// row's: every row is scored on the same views). `budget` adds steps, seconds per step and FPS.
fn table(ablation: &Ablation, pick: Pick, budget: bool) -> String {
    let gs_titles = ["I_gs PSNR", "I_gs SSIM", "I_gs LPIPS", "NVS - I_gs (dB)"];
    let (before, after): (&[&str], Vec<&str>) = if budget {
        (&["steps", "s / step"], [&gs_titles[..], &["FPS"]].concat())
    } else {
        (&[], gs_titles.to_vec())
    };
    let mut table = ScoreTable::new("row")
        .before(before.iter().copied())
        .after(after.iter().copied());
    let none = |n: usize| vec![NO_VALUE.to_string(); n];
    let missing = ImageScores {
        psnr: f64::NAN,
        ssim: f64::NAN,
        lpips: f64::NAN,
    };
    for row in &ablation.rows {
        let (model, gs, _) = pick(row);
        let model = model.unwrap_or(missing);
        let mut cells: Vec<String> = match gs {
            Some(gs) => [
                &score_cells(&gs)[..],
                &[format!("{:+.2}", model.psnr - gs.psnr)],
            ]
            .concat(),
            None => none(4),
        };
        let mut first = Vec::new();
        if budget {
            first = vec![
                row.steps.to_string(),
                format!("{:.2}", row.seconds_per_step),
            ];
            cells.push(format!("{:.1}", row.fps));
        }
        table.row(&row.label, &first, &model, &cells);
    }
    if let Some(copy) = ablation.rows.first().and_then(|r| pick(r).2) {
        table.row(
            "copy source (view 0)",
            &none(before.len()),
            &copy,
            &none(after.len()),
        );
    }
    table.to_markdown()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scores(psnr: f64) -> ImageScores {
        ImageScores {
            psnr,
            ssim: 0.5,
            lpips: 0.25,
        }
    }

    #[test]
    fn rows_show_their_own_render_and_the_baseline() {
        let row = |name: &str, gs: Option<f64>| RowResult {
            row: name.into(),
            label: name.into(),
            steps: 10,
            views: 2,
            seconds_per_step: 0.125,
            fps: 40.0,
            model: scores(20.0),
            model_disoccluded: Some(scores(11.0)),
            gs: gs.map(scores),
            gs_disoccluded: gs.map(|_| scores(12.5)),
            copy_source: scores(18.0),
            copy_source_disoccluded: Some(scores(9.0)),
            provenance: Default::default(),
        };
        let ablation = Ablation {
            config: "tiny".into(),
            teacher_steps: 10,
            student_steps: 5,
            views: 2,
            rows: vec![row("teacher", Some(19.5)), row("no_gs", None)],
        };
        let md = ablation_markdown(&ablation);
        assert!(
            md.contains(
                "| teacher | 10 | 0.12 | 20.000 | 0.5000 | 0.2500 | 19.500 | 0.5000 | 0.2500 \
                 | +0.50 | 40.0 |"
            ),
            "{md}"
        );
        assert!(
            md.contains("| no_gs | 10 | 0.12 | 20.000 | 0.5000 | 0.2500 | - | - | - | - | 40.0 |"),
            "{md}"
        );
        assert!(
            md.contains(
                "| copy source (view 0) | - | - | 18.000 | 0.5000 | 0.2500 | - | - | - | - | - |"
            ),
            "{md}"
        );
        // The region's table: the row's render is 1.5 dB better there.
        assert!(
            md.contains(
                "| teacher | 11.000 | 0.5000 | 0.2500 | 12.500 | 0.5000 | 0.2500 | -1.50 |"
            ),
            "{md}"
        );
        assert!(md.contains("| copy source (view 0) | 9.000 |"), "{md}");
    }
}
