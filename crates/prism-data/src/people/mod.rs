//! Procedural people (work in progress).
