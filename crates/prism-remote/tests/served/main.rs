//! prism-remote's in-process tests, in one test binary: each module starts `prism serve`'s
//! server in a thread of this process, and one binary compiles the served backend once.

mod burn_all_reduce;
mod common;
mod geometry;
mod handshake;
