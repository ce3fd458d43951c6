//! Training across machines on Burn's remote backend.
//!
//! - [`serve`]: `prism serve`, this machine's devices served to a trainer;
//! - [`DeviceList`]: the `--devices` list of a run, local and served devices;
//! - [`connect`]: a run's devices connected, each server checked by prism's [`handshake`];
//! - [`read_token`]: the shared credential, from a file or the environment;
//! - [`shard`]: each served device's share of a batch, loaded by its own server;
//! - [`digest`]: the dataset digest trainer and servers compare, of the files' contents.

pub mod connect;
pub mod credential;
pub mod digest;
pub mod handshake;
pub mod serve;
pub mod shard;
pub mod spec;

pub use connect::{ConnectError, Connected, accepts_connections, connect};
pub use credential::{CredentialError, MIN_TOKEN_BYTES, TOKEN_ENV, read_token};
pub use digest::dataset_digest;
pub use handshake::{Fingerprint, config_digest};
pub use serve::{ServeError, ServeOptions, TransportKind, serve, stop_signal};
pub use shard::ShardRequest;
pub use spec::{DeviceList, DeviceSpec, SpecError};
