//! The viewing protocol of the paper's dataset (supplement, "Static Dataset Construction").
//!
//! Each subject is scaled to a height of 1.80 m +- 0.05 m, stands on `y = 0` facing +Z and is
//! shifted by up to +-0.1 m horizontally and in depth. 105 cameras sit on a sphere of radius
//! 2.0 m around the nominal body centre `(0, height / 2, 0)`: view 0 frontal, views 1..=100
//! with yaw and pitch uniform in [-30, 30] degrees, views 101..=104 the four corners.
//! The sphere stays fixed while the subject moves, so the translation shows up as framing
//! variation, as in the paper's renders.

use glam::{Mat4, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::camera::{Camera, Intrinsics};

/// Number of views per subject: frontal + 100 random + 4 corners.
pub const NUM_VIEWS: usize = 105;
/// Index of the source (frontal) view.
pub const SOURCE_VIEW: usize = 0;
/// Views 1..=100: the random views used as evaluation targets.
pub const EVAL_TARGETS: std::ops::RangeInclusive<usize> = 1..=100;
/// Views 1..=104: every view that can be a training target.
pub const TRAIN_TARGETS: std::ops::RangeInclusive<usize> = 1..=104;

/// The protocol's parameters; [`ViewingProtocol::default`] is the paper's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewingProtocol {
    /// Radius of the camera sphere in metres.
    pub radius: f32,
    /// Largest |yaw| and |pitch| in degrees.
    pub max_angle_deg: f32,
    /// Number of random views (between the frontal view and the corners).
    pub random_views: usize,
    /// Nominal subject height in metres.
    pub height: f32,
    /// Half-width of the uniform height jitter in metres.
    pub height_jitter: f32,
    /// Half-width of the uniform horizontal (x) and depth (z) translation in metres.
    pub translation: f32,
}

impl Default for ViewingProtocol {
    fn default() -> Self {
        Self {
            radius: 2.0,
            max_angle_deg: 30.0,
            random_views: 100,
            height: 1.80,
            height_jitter: 0.05,
            translation: 0.1,
        }
    }
}

/// One view of the protocol: its index and orbit angles.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewAngles {
    /// View index (0 is the frontal source view).
    pub index: usize,
    /// Yaw in degrees (positive: camera towards +X).
    pub yaw_deg: f32,
    /// Pitch in degrees (positive: camera above).
    pub pitch_deg: f32,
}

/// How a subject is placed in the world: a uniform scale to its drawn height, then a
/// translation (horizontal and depth jitter).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// The subject's height after normalisation, metres.
    pub height: f32,
    /// World translation applied after scaling (y is 0: the subject stays on the floor).
    pub translation: [f32; 3],
}

impl Placement {
    /// The similarity transform from a subject standing on `y = 0` with its own height
    /// `source_height` to the world: scale to `self.height`, then translate.
    pub fn transform(&self, source_height: f32) -> Mat4 {
        Mat4::from_translation(Vec3::from_array(self.translation))
            * Mat4::from_scale(Vec3::splat(self.height / source_height))
    }
}

impl ViewingProtocol {
    /// The protocol's views for one subject, drawn from `seed`: view 0 frontal, the random views
    /// uniform in the square of half-width `max_angle_deg`, then the four corners.
    pub fn views(&self, seed: u64) -> Vec<ViewAngles> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let a = self.max_angle_deg;
        let mut views = vec![ViewAngles {
            index: 0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
        }];
        for i in 0..self.random_views {
            views.push(ViewAngles {
                index: i + 1,
                yaw_deg: rng.random_range(-a..=a),
                pitch_deg: rng.random_range(-a..=a),
            });
        }
        for (k, (yaw, pitch)) in [(-a, -a), (a, -a), (-a, a), (a, a)].into_iter().enumerate() {
            views.push(ViewAngles {
                index: self.random_views + 1 + k,
                yaw_deg: yaw,
                pitch_deg: pitch,
            });
        }
        views
    }

    /// The subject's placement drawn from `seed` (independent of the views' draw).
    pub fn placement(&self, seed: u64) -> Placement {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
        let j = self.height_jitter;
        let t = self.translation;
        Placement {
            height: self.height + rng.random_range(-j..=j),
            translation: [rng.random_range(-t..=t), 0.0, rng.random_range(-t..=t)],
        }
    }

    /// Centre of the camera sphere: the nominal body centre.
    pub fn center(&self) -> Vec3 {
        Vec3::new(0.0, self.height / 2.0, 0.0)
    }

    /// The camera of a view, with the given intrinsics.
    pub fn camera(&self, view: &ViewAngles, intrinsics: Intrinsics) -> Camera {
        Camera::orbit(
            view.yaw_deg,
            view.pitch_deg,
            self.radius,
            self.center(),
            intrinsics,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn protocol_has_105_views_in_range_with_corners() {
        let p = ViewingProtocol::default();
        let v = p.views(7);
        assert_eq!(v.len(), NUM_VIEWS);
        assert_eq!((v[0].yaw_deg, v[0].pitch_deg), (0.0, 0.0));
        for (i, view) in v.iter().enumerate() {
            assert_eq!(view.index, i);
            assert!(view.yaw_deg.abs() <= 30.0 && view.pitch_deg.abs() <= 30.0);
        }
        let corners: Vec<_> = v[101..]
            .iter()
            .map(|c| (c.yaw_deg.abs(), c.pitch_deg.abs()))
            .collect();
        assert_eq!(corners, vec![(30.0, 30.0); 4]);
        // The random views spread over the square (a uniform draw of 100 hits every quadrant).
        for (sy, sp) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            assert!(
                v[1..=100]
                    .iter()
                    .any(|x| x.yaw_deg * sy > 0.0 && x.pitch_deg * sp > 0.0)
            );
        }
    }

    #[test]
    fn draws_are_reproducible_and_seed_dependent() {
        let p = ViewingProtocol::default();
        assert_eq!(p.views(3), p.views(3));
        assert_ne!(p.views(3), p.views(4));
        assert_eq!(p.placement(3), p.placement(3));
        for seed in 0..200 {
            let pl = p.placement(seed);
            assert!((pl.height - 1.80).abs() <= 0.05 + 1e-6);
            assert!(pl.translation[0].abs() <= 0.1 && pl.translation[2].abs() <= 0.1);
            assert_eq!(pl.translation[1], 0.0);
        }
    }

    #[test]
    fn cameras_sit_on_the_sphere() {
        let p = ViewingProtocol::default();
        let k = Intrinsics::protocol_default(32, 32);
        for view in p.views(1) {
            let c = p.camera(&view, k);
            assert!(((c.center() - p.center()).length() - 2.0).abs() < 1e-5);
        }
    }

    #[test]
    fn placement_scales_to_height_and_translates() {
        let pl = Placement {
            height: 1.8,
            translation: [0.05, 0.0, -0.02],
        };
        let m = pl.transform(0.9);
        let top = m.transform_point3(Vec3::new(0.0, 0.9, 0.0));
        assert!((top - Vec3::new(0.05, 1.8, -0.02)).length() < 1e-6);
    }
}
