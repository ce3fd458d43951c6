//! The files of an evaluation: `evaluation.json`, the Markdown report (its tables through
//! [`ScoreTable`]), the per-subject grids and the run's training curves.

use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

use prism_data::{RegionMethod, SplitKind};
use prism_losses::{NO_VALUE, ScoreTable, score_cells};

use crate::error::{Result, TrainError};
use crate::evaluate::{Evaluation, SubjectGrid};
use crate::images::{save_png, save_text};
use crate::log::METRICS_FILE;
use crate::plot::{PLOT_FILE, plot_metrics};
use crate::tally::{MeanScores, MethodScores};

/// File name of the JSON scores in an evaluation folder.
pub const EVALUATION_JSON: &str = "evaluation.json";
/// File name of the Markdown report in an evaluation folder.
pub const REPORT_MD: &str = "report.md";
/// Folder of the per-subject PNG grids in an evaluation folder.
pub const GRIDS_DIR: &str = "grids";
/// File name, in an evaluation folder, of the training curves of the checkpoint's run.
pub const TRAINING_CURVES_PNG: &str = "training-curves.png";

/// The files an evaluation wrote.
#[derive(Clone, Debug)]
pub struct EvaluationFiles {
    /// `evaluation.json`.
    pub json: PathBuf,
    /// `report.md`.
    pub report: PathBuf,
    /// One PNG grid per subject.
    pub grids: Vec<PathBuf>,
    /// The training curves of the checkpoint's run ([`TRAINING_CURVES_PNG`]), when its run
    /// folder was known.
    pub training_curves: Option<PathBuf>,
}

/// Writes `evaluation.json`, `report.md` and `grids/SUBJECT.png` into `dir` (created), each
/// atomically. `title` heads the report (e.g. the checkpoint evaluated). With the checkpoint's
/// `run` folder, its training curves (its [`PLOT_FILE`], or, for a run without one, a plot of
/// its `metrics.jsonl`) are put beside the report as [`TRAINING_CURVES_PNG`] and shown in it.
///
/// # Errors
/// I/O errors, naming the file; a plot that cannot be drawn.
pub fn write_evaluation(
    dir: &Path,
    title: &str,
    evaluation: &Evaluation,
    grids: &[SubjectGrid],
    run: Option<&Path>,
) -> Result<EvaluationFiles> {
    let grid_dir = dir.join(GRIDS_DIR);
    fs::create_dir_all(&grid_dir).map_err(|e| TrainError::io(&grid_dir, e))?;
    let mut grid_paths = Vec::new();
    for grid in grids {
        let path = grid_dir.join(format!("{}.png", grid.subject));
        save_png(&path, &grid.image)?;
        grid_paths.push(path);
    }
    let training_curves = match run {
        Some(run) => training_curves(run, &dir.join(TRAINING_CURVES_PNG))?,
        None => None,
    };
    let json = dir.join(EVALUATION_JSON);
    save_text(&json, &evaluation_json(evaluation))?;
    let report = dir.join(REPORT_MD);
    save_text(
        &report,
        &markdown_report(
            title,
            evaluation,
            &grid_paths,
            training_curves.as_deref(),
            dir,
        ),
    )?;
    Ok(EvaluationFiles {
        json,
        report,
        grids: grid_paths,
        training_curves,
    })
}

/// Puts the training curves of `run` at `out`: a copy of its [`PLOT_FILE`], or a plot of its
/// `metrics.jsonl` when it has no plot; `None` when it has neither.
fn training_curves(run: &Path, out: &Path) -> Result<Option<PathBuf>> {
    let plot = run.join(PLOT_FILE);
    let metrics = run.join(METRICS_FILE);
    if plot.is_file() {
        let bytes = fs::read(&plot).map_err(|e| TrainError::io(&plot, e))?;
        prism_core::files::write_bytes(out, &bytes).map_err(|e| TrainError::io(out, e))?;
    } else if metrics.is_file() {
        let name = run.file_name().unwrap_or(run.as_os_str()).to_string_lossy();
        plot_metrics(&metrics, out, &format!("training curves of {name}"))?;
    } else {
        return Ok(None);
    }
    Ok(Some(out.to_path_buf()))
}

/// The evaluation as pretty JSON (NaN written as `null`).
pub fn evaluation_json(evaluation: &Evaluation) -> String {
    serde_json::to_string_pretty(evaluation).expect("evaluation serialises") + "\n"
}

/// The report's first table: the means of the model (with its FPS), of its 3DGS head's render
/// (when it has one), of the copy of the source view and of the true-depth warp.
fn means_table(e: &Evaluation) -> ScoreTable {
    let mut table = ScoreTable::new("prediction").after(["FPS (1 pair)"]);
    table.row(
        "model (NVS decoder I_t)",
        &[],
        &e.mean(),
        &[format!("{:.2}", e.fps)],
    );
    if let Some(gs) = &e.gs {
        table.row(
            "model's 3DGS head (I_gs)",
            &[],
            &gs.mean(),
            &[NO_VALUE.into()],
        );
    }
    let copy = e.copy_source.mean();
    table.row("copy source (view 0)", &[], &copy, &[NO_VALUE.into()]);
    let warp = e.true_depth_warp.mean();
    table.row(WARP_ROW, &[], &warp, &[NO_VALUE.into()]);
    table
}

/// The true-depth warp's row name in the report's tables.
const WARP_ROW: &str = "source warped at the true depth";

/// The means in the disoccluded region of the model, its 3DGS head (when it has one), the
/// copy of the source view and the true-depth warp; `None` when they were not measured.
fn disoccluded_table(e: &Evaluation) -> Option<ScoreTable> {
    let mut table = ScoreTable::new("prediction (disoccluded region)");
    table.row(
        "model (NVS decoder I_t)",
        &[],
        &e.disoccluded?.scores(),
        &[],
    );
    if let Some(gs) = e.gs.as_ref().and_then(|g| g.disoccluded) {
        table.row("model's 3DGS head (I_gs)", &[], &gs.scores(), &[]);
    }
    if let Some(copy) = e.copy_source.disoccluded {
        table.row("copy source (view 0)", &[], &copy.scores(), &[]);
    }
    if let Some(warp) = e.true_depth_warp.disoccluded {
        table.row(WARP_ROW, &[], &warp.scores(), &[]);
    }
    Some(table)
}

/// A per-subject or per-angle table, its rows named in a column titled `name`: the number of
/// views and the model's three scores, then PSNR and LPIPS of each of `others`.
fn breakdown_table(name: &str, others: &[(&str, &MethodScores)]) -> ScoreTable {
    let after = others
        .iter()
        .flat_map(|(o, _)| [format!("{o} PSNR"), format!("{o} LPIPS")]);
    ScoreTable::new(name).before(["views"]).after(after)
}

/// A row of a [`breakdown_table`]: `model`'s views and scores, and PSNR and LPIPS of the others
/// on the same views (`None`: the other has no scores there).
fn breakdown_row(
    table: &mut ScoreTable,
    name: String,
    model: &MeanScores,
    others: &[Option<&MeanScores>],
) {
    let after: Vec<String> = others
        .iter()
        .flat_map(|o| match o {
            Some(o) => {
                let [psnr, _, lpips] = score_cells(&o.mean);
                [psnr, lpips]
            }
            None => [NO_VALUE.into(), NO_VALUE.into()],
        })
        .collect();
    table.row(name, &[model.views.to_string()], &model.mean, &after);
}

/// The speckle section: each method's speckle score beside the truth's own Laplacian.
fn speckle_section(e: &Evaluation) -> String {
    let s = &e.speckle;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "## Speckle\n\nEach prediction's mean absolute Laplacian over the truth's, on the \
         pixels of the target's foreground where the truth is smooth (the truth's own mean \
         there: {:.5}). 1 is as smooth as the truth; pixel-level colour noise raises it.\n\n\
         | prediction | speckle |\n|---|---:|",
        s.truth_laplacian
    );
    let mut rows = vec![("model (NVS decoder I_t)", Some(s.model))];
    rows.push(("model's 3DGS head (I_gs)", s.gs));
    rows.push(("copy source (view 0)", Some(s.copy_source)));
    rows.push((WARP_ROW, Some(s.true_depth_warp)));
    for (name, value) in rows {
        if let Some(v) = value {
            let _ = writeln!(out, "| {name} | {v:.2} |");
        }
    }
    out.push('\n');
    out
}

/// The oracle section, when the evaluation has the swaps: PSNR overall and in the disoccluded
/// region of each swap's `I_gs` and `I_t`, with the dB each gains over the model's own.
fn oracle_section(e: &Evaluation) -> Option<String> {
    let rows = e.oracle.as_ref()?;
    let base = rows.first()?;
    let region = |m: &MethodScores| m.disoccluded.map_or(f64::NAN, |d| d.psnr_disoccluded);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "## Oracle swaps\n\nThe 3DGS head's Gaussians drawn again with one property taken \
         from the truth (depth from the dataset's points, the source pixels' colours, \
         opacities from the source mask, isotropic sizes of {} source pixels; the depth error \
         also halved and quartered instead of removed), and the NVS decoder's output on each \
         render. Gains are over the first row.\n\n\
         | swap | I_gs PSNR | gain | in region | I_t PSNR | gain | in region | I_gs speckle | \
         I_t speckle |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        e.true_depth_warp_footprint
    );
    for row in rows {
        let _ = writeln!(
            out,
            "| {} | {:.3} | {:+.3} | {:.3} | {:.3} | {:+.3} | {:.3} | {:.2} | {:.2} |",
            row.swap.name(),
            row.gs.psnr,
            row.gs.psnr - base.gs.psnr,
            region(&row.gs),
            row.nvs.psnr,
            row.nvs.psnr - base.nvs.psnr,
            region(&row.nvs),
            row.gs_speckle,
            row.nvs_speckle
        );
    }
    if let Some(d) = &e.depth_error {
        let _ = writeln!(
            out,
            "\nThe model's Gaussians lie {:.2} cm from the dataset's points on average over the \
             source foreground (median {:.2} cm, 90th percentile {:.2} cm; each on its pixel's \
             ray, so this is their depth error, {:+.2} cm on average with its sign, positive \
             behind the truth): what the depth swap removes.",
            d.mean * 100.0,
            d.median * 100.0,
            d.p90 * 100.0,
            d.bias * 100.0
        );
    }
    out.push('\n');
    Some(out)
}

/// The rows of the report's tables after the model's: the 3DGS head's `I_gs` (when there is
/// one) and the copy of the source view, with their names.
fn other_rows(e: &Evaluation) -> Vec<(&'static str, &MethodScores)> {
    let mut rows = Vec::new();
    if let Some(gs) = &e.gs {
        rows.push(("I_gs", gs));
    }
    rows.push(("copy source", &e.copy_source));
    rows
}

/// The Markdown report: the means of the model, of its 3DGS head (if any) and of the copy of
/// the source view; per-subject and per-angle tables with the same three; the training curves
/// and links to the grids (relative to `dir`).
pub fn markdown_report(
    title: &str,
    evaluation: &Evaluation,
    grids: &[PathBuf],
    training_curves: Option<&Path>,
    dir: &Path,
) -> String {
    let e = evaluation;
    let mut out = String::new();
    let _ = writeln!(out, "# Evaluation of {title}\n");
    let _ = writeln!(
        out,
        "{} test subjects, source view 0, {} target views each, {} x {} px. Each subject's \
         views are averaged, then the subjects. \"copy source\" takes the source view as the \
         prediction of every target view: the baseline a model must beat.\n",
        e.subjects.len(),
        e.views_per_subject,
        e.resolution,
        e.resolution
    );
    out.push_str(&means_table(e).to_markdown());
    let c = &e.copy_source;
    let _ = writeln!(
        out,
        "\nModel minus copy source: PSNR {:+.3} dB, SSIM {:+.4}, LPIPS {:+.4} (the model beats \
         the baseline where PSNR and SSIM are positive and LPIPS negative).\n",
        e.psnr - c.psnr,
        e.ssim - c.ssim,
        e.lpips - c.lpips
    );
    let sweep: Vec<String> = e
        .true_depth_warp_sweep
        .iter()
        .map(|f| format!("{} px {:.3} dB", f.footprint, f.psnr))
        .collect();
    let _ = writeln!(
        out,
        "The source warped at the true depth, a baseline, is its foreground pixels as Gaussians \
         at the dataset's own 3D points, rendered into each target view: what a geometric \
         output shows with the dataset's depth and the source's colours. Its Gaussians' size \
         matters, so it was rendered at several footprints ({}) on {}, and the best there, {} \
         source pixels, is the one scored here. Model minus it: PSNR {:+.3} dB.\n",
        sweep.join(", "),
        match e.true_depth_warp_chosen_on {
            SplitKind::Train => "training subjects",
            SplitKind::Test => {
                "the test subjects themselves, as this dataset has no training subjects (the \
                 baseline is at its best on these views)"
            }
        },
        e.true_depth_warp_footprint,
        e.psnr - e.true_depth_warp.psnr
    );
    if let Some(table) = disoccluded_table(e) {
        let how = match e.disoccluded_by {
            RegionMethod::DepthTest => {
                "each target pixel's surface point, from the dataset's depth maps, tested against \
                 the source's depth map"
            }
            RegionMethod::Estimate => {
                "an estimate: this dataset stores no depth maps, so the source's visible surface \
                 is reprojected into the target without occlusion there, which misses \
                 disoccluded pixels; synthesise the dataset again for the exact region"
            }
        };
        let _ = writeln!(
            out,
            "## In the disoccluded region\n\nThe same scores on each target view's foreground \
             that the source view does not see ({how}; views without such pixels left out): \
             there a warp of the source has nothing to copy. LPIPS there is that of the \
             prediction pasted into the ground truth on the region.\n"
        );
        out.push_str(&table.to_markdown());
        if let Some(d) = e.disoccluded {
            let bound = match e.disoccluded_by {
                RegionMethod::DepthTest => {
                    "the most that a better guess of what the source does not see can add"
                }
                RegionMethod::Estimate => {
                    "not a bound, since the estimated region misses disoccluded pixels"
                }
            };
            let _ = writeln!(
                out,
                "\nWith this region taken from the ground truth the model would score {:.3} dB \
                 overall ({:+.3} dB): {bound}.",
                d.psnr_region_filled,
                d.psnr_region_filled - e.psnr
            );
        }
        out.push('\n');
    }
    out.push_str(&speckle_section(e));
    if let Some(section) = oracle_section(e) {
        out.push_str(&section);
    }
    let others = other_rows(e);
    let _ = writeln!(out, "## Per subject\n");
    let mut table = breakdown_table("subject", &others);
    for (name, s) in &e.subjects {
        let rest: Vec<_> = others.iter().map(|(_, o)| o.subjects.get(name)).collect();
        breakdown_row(&mut table, name.clone(), s, &rest);
    }
    out.push_str(&table.to_markdown());
    for axis in ["yaw", "pitch"] {
        let _ = writeln!(out, "\n## By |{axis}|\n");
        let mut table = breakdown_table(&format!("abs {axis} (deg)"), &others);
        for b in e.per_angle.axis(axis) {
            let rest: Vec<_> = others
                .iter()
                .map(|(_, o)| {
                    o.per_angle
                        .axis(axis)
                        .iter()
                        .find(|ob| ob.from_deg == b.from_deg)
                        .map(|ob| &ob.scores)
                })
                .collect();
            let name = format!("{:.0}-{:.0}", b.from_deg, b.to_deg);
            breakdown_row(&mut table, name, &b.scores, &rest);
        }
        out.push_str(&table.to_markdown());
    }
    if let Some(path) = training_curves {
        let rel = path.strip_prefix(dir).unwrap_or(path);
        let _ = writeln!(
            out,
            "\n## Training curves\n\nThe run's loss terms, and its validation PSNR, SSIM and \
             LPIPS with the copy-source baseline (dashed), from its metrics.jsonl.\n\n![training \
             curves]({})",
            rel.display()
        );
    }
    if !grids.is_empty() {
        let _ = writeln!(
            out,
            "\n## Samples\n\nPer row: source | prediction | ground truth | error map (mean \
             absolute error, black 0, white {} and above).\n",
            crate::images::ERROR_MAP_FULL_SCALE
        );
        for path in grids {
            let rel = path.strip_prefix(dir).unwrap_or(path);
            let _ = writeln!(out, "![{}]({})\n", rel.display(), rel.display());
        }
    }
    out
}
