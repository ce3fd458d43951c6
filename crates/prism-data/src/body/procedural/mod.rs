//! A procedural humanoid in SMPL-X's layout (work in progress).
