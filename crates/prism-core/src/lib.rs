//! The ground every prism crate stands on: cameras and Plücker rays, the paper's viewing
//! protocol, the run-time backend choice, the count of host reads, the phase timings, the
//! hypervisor's steal share of a timed stretch, atomic file writes and image conversion.
//!
//! Conventions (shared by every crate of the workspace): metres, world Y-up, subjects stand on
//! `y = 0` facing +Z; OpenCV cameras (x right, y down, looking along +z) given by pixel
//! intrinsics and a 4x4 camera-to-world matrix; pixel centres at `(x + 0.5, y + 0.5)`;
//! images as `[B, 3, H, W]` tensors in [0, 1].

pub mod axes;
pub mod backend;
pub mod camera;
pub mod camera_record;
pub mod files;
pub mod images;
pub mod phases;
pub mod progress;
pub mod protocol;
pub mod rays;
pub mod reads;
pub mod served;
pub mod steal;

pub use backend::{BackendError, BackendKind};
pub use camera::{Camera, Intrinsics};
pub use camera_record::CameraRecord;
pub use files::write_atomic;
pub use protocol::{Placement, ViewAngles, ViewingProtocol};
