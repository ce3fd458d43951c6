//! The dataset format of prism (see `FORMAT.md`): writing, reading, validating, and turning
//! subjects into training batches. What a dataset holds is made elsewhere (`prism-synth`
//! renders procedural people and scans into it); this crate only knows the files.

pub mod batch;
pub mod check;
pub mod disocclusion;
pub mod error;
pub mod io;
pub mod plan;
pub mod reader;
pub mod samples;
pub mod schema;
pub mod synth_options;
pub mod writer;

pub use batch::{BatchPixels, PIXEL_PLANES, PairInfo, PrismBatch, PrismBatcher};
pub use check::{CheckReport, Problem, check_dataset};
pub use disocclusion::{
    DepthView, FOREGROUND, RegionMethod, disoccluded_by_depth, disoccluded_region,
};
pub use error::DataError;
pub use io::{DepthMap, Mask, PointMap};
pub use reader::DatasetReader;
pub use samples::{Sample, SampleDataset, SampleMeta, TargetSelection, View, ViewMeta};
pub use schema::{CameraRecord, DatasetMeta, Split, SplitKind, SubjectRecord};
pub use synth_options::SynthOptions;
pub use writer::{DatasetWriter, SubjectWriter};
