//! Stage II of the cascade (paper Sec. 3.2): the geometry branches on `T_mid` and the injection
//! that adds their features to the sequence before stage III.
//!
//! - [`smplx`]: the SMPL-X branch (parameters, posed body, position map, triplane features
//!   `F_smpl`), with the body model, the 6D rotations and the weak-perspective placement;
//! - [`points`]: the point branch (DPT point map and confidence, splatted features `F_pts`);
//! - [`injection`]: zero convolutions and gates, `T'_mid` from `T_mid`, `T_in`, `F_smpl` and
//!   `F_pts`.

pub(crate) mod injection;
pub(crate) mod points;
pub(crate) mod smplx;
