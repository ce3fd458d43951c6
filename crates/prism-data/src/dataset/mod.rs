//! The dataset format of prism (see `FORMAT.md`): writing, reading, validating, and turning
//! subjects into training batches.

pub mod batch;
pub mod check;
pub mod error;
pub mod io;
pub mod plan;
pub mod reader;
pub mod render_subject;
pub mod samples;
pub mod schema;
pub mod writer;

pub use batch::{PairInfo, PrismBatch, PrismBatcher};
pub use check::{CheckReport, Problem, check_dataset};
pub use error::DataError;
pub use io::{Mask, PointMap};
pub use reader::DatasetReader;
pub use render_subject::ProtocolRenderer;
pub use samples::{Sample, SampleDataset, TargetSelection, View};
pub use schema::{CameraRecord, DatasetMeta, Split, SplitKind, SubjectRecord};
pub use writer::{DatasetWriter, SubjectWriter};
