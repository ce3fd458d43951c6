//! The one formatter of score tables: rows of named scores (PSNR, SSIM, LPIPS) as Markdown,
//! with columns of other values before and after the scores. The evaluation report, the quick
//! start's table and the tables of `prism metrics` and `prism evaluate --pred --gt` are all
//! [`ScoreTable`]s, so the same score reads the same everywhere.

use crate::ImageScores;

/// The titles of the three score columns.
pub const SCORE_COLUMNS: [&str; 3] = ["PSNR (dB)", "SSIM", "LPIPS"];
/// The cell of a value that a row does not have.
pub const NO_VALUE: &str = "-";

/// The cells of `scores`: PSNR to 3 decimals (dB), SSIM and LPIPS to 4.
pub fn score_cells(scores: &ImageScores) -> [String; 3] {
    [
        format!("{:.3}", scores.psnr),
        format!("{:.4}", scores.ssim),
        format!("{:.4}", scores.lpips),
    ]
}

/// A Markdown table of named scores: a column naming each row (left-aligned), then the columns
/// given to [`ScoreTable::before`], the three [`SCORE_COLUMNS`] and the columns given to
/// [`ScoreTable::after`] (right-aligned).
#[derive(Clone, Debug)]
pub struct ScoreTable {
    name: String,
    before: Vec<String>,
    after: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl ScoreTable {
    /// An empty table whose first column is titled `name`.
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            before: Vec::new(),
            after: Vec::new(),
            rows: Vec::new(),
        }
    }

    /// The table with columns `titles` between the names and the scores.
    pub fn before<S: Into<String>>(mut self, titles: impl IntoIterator<Item = S>) -> Self {
        self.before = titles.into_iter().map(Into::into).collect();
        self
    }

    /// The table with columns `titles` after the scores.
    pub fn after<S: Into<String>>(mut self, titles: impl IntoIterator<Item = S>) -> Self {
        self.after = titles.into_iter().map(Into::into).collect();
        self
    }

    /// Adds the row `name` with `scores`, and the cells `before` and `after` them (one per
    /// column of [`ScoreTable::before`] and [`ScoreTable::after`]; [`NO_VALUE`] where a row has
    /// none).
    ///
    /// # Panics
    /// When `before` or `after` has another number of cells than the table has columns there.
    pub fn row(
        &mut self,
        name: impl Into<String>,
        before: &[String],
        scores: &ImageScores,
        after: &[String],
    ) {
        assert_eq!(before.len(), self.before.len(), "cells before the scores");
        assert_eq!(after.len(), self.after.len(), "cells after the scores");
        let mut cells = vec![name.into()];
        cells.extend_from_slice(before);
        cells.extend(score_cells(scores));
        cells.extend_from_slice(after);
        self.rows.push(cells);
    }

    /// The table as Markdown: the header, the alignment row and a line per row.
    pub fn to_markdown(&self) -> String {
        let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
        let mut head = vec![self.name.clone()];
        head.extend(self.before.iter().cloned());
        head.extend(SCORE_COLUMNS.map(String::from));
        head.extend(self.after.iter().cloned());
        let mut out = line(&head);
        out.push_str("|---|");
        out.push_str(&"---:|".repeat(head.len() - 1));
        out.push('\n');
        for row in &self.rows {
            out.push_str(&line(row));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_of_named_scores_with_other_columns() {
        let scores = ImageScores {
            psnr: 21.23456,
            ssim: 0.812345,
            lpips: f64::NAN,
        };
        let mut table = ScoreTable::new("model").before(["steps"]).after(["FPS"]);
        table.row("teacher", &["3".into()], &scores, &["1.50".into()]);
        table.row("copy", &[NO_VALUE.into()], &scores, &[NO_VALUE.into()]);
        assert_eq!(
            table.to_markdown(),
            "| model | steps | PSNR (dB) | SSIM | LPIPS | FPS |\n\
             |---|---:|---:|---:|---:|---:|\n\
             | teacher | 3 | 21.235 | 0.8123 | NaN | 1.50 |\n\
             | copy | - | 21.235 | 0.8123 | NaN | - |\n"
        );
    }
}
