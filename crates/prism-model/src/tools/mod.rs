//! What runs around the network rather than in it:
//!
//! - [`info`]: parameter and FLOP counts from a config;
//! - [`bench`]: forward timing, with [`memory`]'s peak-memory probe;
//! - [`lvsm`]: pretrained LVSM checkpoints mapped into a [`crate::Prism`].

pub(crate) mod bench;
pub(crate) mod info;
pub(crate) mod lvsm;
pub(crate) mod memory;
