//! The rows of the ablation table: the paper's (Table 3) and prism's output recipe, each as the
//! change it makes to the config.

use prism_model::{DistillMode, GsColour, GsDepth, NvsOutput};

use crate::config::TrainingConfig;

/// One row of `prism ablate`: a model trained at the ablation's budget.
///
/// Teacher rows are full-attention models trained from scratch for the teacher budget; student
/// rows are distilled from the [`AblationRow::Teacher`] row for the student budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum AblationRow {
    /// The full-attention teacher, the config as it is.
    Teacher,
    /// The student of the paper's progressive stitching (the "full model").
    Progressive,
    /// Every switchable block linear from the first step ("w/o progressive distil.").
    AllAtOnce,
    /// Every block linear, the last of each group too ("fully linear attention").
    FullyLinear,
    /// The teacher without the SMPL-X branch's position-map features ("w/o pos. map feat.").
    NoSmplx,
    /// The teacher without the point branch's features ("w/o point map feat."); its 3DGS head
    /// places the Gaussians at its own depths.
    NoPoints,
    /// The teacher without the 3DGS head; its NVS decoder regresses the colours.
    NoGs,
    /// The progressive student trained on the images only (no `L_distill`, the teacher is not
    /// run).
    NoDistill,
    /// The teacher with the paper's plain outputs: the NVS decoder regresses the colours and
    /// the 3DGS head its colours, instead of prism's recipe (a correction of `I_gs`, the source
    /// pixels' colours).
    Plain,
}

impl AblationRow {
    /// Every row, in the table's order.
    pub const ALL: [AblationRow; 9] = [
        Self::Teacher,
        Self::Progressive,
        Self::AllAtOnce,
        Self::FullyLinear,
        Self::NoSmplx,
        Self::NoPoints,
        Self::NoGs,
        Self::NoDistill,
        Self::Plain,
    ];

    /// The row's name in `--rows` and its folder's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Teacher => "teacher",
            Self::Progressive => "progressive",
            Self::AllAtOnce => "all_at_once",
            Self::FullyLinear => "fully_linear",
            Self::NoSmplx => "no_smplx",
            Self::NoPoints => "no_points",
            Self::NoGs => "no_gs",
            Self::NoDistill => "no_distill",
            Self::Plain => "plain",
        }
    }

    /// The row's label in the table.
    pub fn label(self) -> &'static str {
        match self {
            Self::Teacher => "teacher (full attention)",
            Self::Progressive => "student, progressive stitching",
            Self::AllAtOnce => "student, all-at-once stitching",
            Self::FullyLinear => "student, fully linear",
            Self::NoSmplx => "teacher w/o SMPL-X pos. map feat.",
            Self::NoPoints => "teacher w/o point map feat.",
            Self::NoGs => "teacher w/o 3DGS head",
            Self::NoDistill => "student w/o distillation",
            Self::Plain => "teacher, paper's plain outputs",
        }
    }

    /// Whether the row is distilled from the teacher row.
    pub fn is_student(self) -> bool {
        matches!(
            self,
            Self::Progressive | Self::AllAtOnce | Self::FullyLinear | Self::NoDistill
        )
    }

    /// The row of `name` (see [`AblationRow::name`]).
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|row| row.name() == name)
    }

    /// The rows of a `--rows` list: `all`, or names separated by commas. The teacher row is
    /// added when a student row needs it; the rows come in the table's order.
    ///
    /// # Errors
    /// An unknown or missing name, with the names there are.
    pub fn parse_list(list: &str) -> Result<Vec<Self>, String> {
        if list.trim() == "all" {
            return Ok(Self::ALL.to_vec());
        }
        let mut rows = Vec::new();
        for name in list.split(',').map(str::trim) {
            let row = Self::parse(name).ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|r| r.name()).collect();
                format!(
                    "unknown ablation row {name:?}: the rows are all or {}",
                    names.join(", ")
                )
            })?;
            rows.push(row);
        }
        if rows.iter().any(|r| r.is_student()) {
            rows.push(Self::Teacher);
        }
        rows.sort();
        rows.dedup();
        Ok(rows)
    }

    /// `base` changed as the row says (the student rows' `[distill]` mode and `L_distill`
    /// weight; the teacher rows' `[model]` parts).
    pub fn config(self, base: &TrainingConfig) -> TrainingConfig {
        let mut config = base.clone();
        let model = &mut config.model;
        match self {
            Self::Teacher => {}
            Self::Progressive => config.distill.mode = DistillMode::Progressive,
            Self::AllAtOnce => config.distill.mode = DistillMode::AllAtOnce,
            Self::FullyLinear => config.distill.mode = DistillMode::FullyLinear,
            Self::NoDistill => {
                config.distill.mode = DistillMode::Progressive;
                config.losses.distill = 0.0;
            }
            Self::NoSmplx => model.smplx_branch = false,
            Self::NoPoints => {
                model.point_branch = false;
                model.gs_depth = GsDepth::Head;
            }
            Self::NoGs => {
                model.gs_head = false;
                model.nvs_output = NvsOutput::Direct;
            }
            Self::Plain => {
                model.nvs_output = NvsOutput::Direct;
                model.gs_colour = GsColour::Regressed;
            }
        }
        config
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::configs_dir;

    #[test]
    fn lists_parse_in_table_order_with_the_teacher_of_the_students() {
        assert_eq!(
            AblationRow::parse_list("no_points, progressive").unwrap(),
            [
                AblationRow::Teacher,
                AblationRow::Progressive,
                AblationRow::NoPoints
            ]
        );
        assert_eq!(AblationRow::parse_list("all").unwrap(), AblationRow::ALL);
        assert_eq!(
            AblationRow::parse_list("plain").unwrap(),
            [AblationRow::Plain]
        );
        let err = AblationRow::parse_list("teacher,nope").unwrap_err();
        assert!(
            err.contains("\"nope\"") && err.contains("no_distill"),
            "{err}"
        );
    }

    #[test]
    fn every_row_is_a_valid_config() {
        let base = TrainingConfig::load(configs_dir().join("tiny.toml")).unwrap();
        for row in AblationRow::ALL {
            let config = row.config(&base);
            config.model.validate().unwrap();
            let changed = |c: &TrainingConfig| {
                (
                    c.model.smplx_branch,
                    c.model.point_branch,
                    c.model.gs_head,
                    c.model.nvs_output,
                    c.model.gs_colour,
                    c.distill.mode,
                    c.losses.distill,
                )
            };
            // Only the teacher and the progressive student are the config as it is.
            let same = changed(&config) == changed(&base);
            assert_eq!(
                same,
                matches!(row, AblationRow::Teacher | AblationRow::Progressive),
                "{row:?}"
            );
        }
        let plain = AblationRow::Plain.config(&base).model;
        assert_eq!(
            (plain.nvs_output, plain.gs_colour),
            (NvsOutput::Direct, GsColour::Regressed)
        );
    }
}
