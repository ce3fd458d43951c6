//! Scores of views averaged as the paper's evaluation protocol does: each subject's views,
//! then the subjects; and pooled by view angle. Validation during training and `prism
//! evaluate` both add their views' [`ImageScores`] (from [`prism_losses::score_images`]) to a
//! [`Tally`], so the same views get the same means.

use std::collections::BTreeMap;

use prism_data::Sample;
use prism_losses::ImageScores;
use serde::Serialize;

/// Width of the view-angle bins of the breakdown, degrees.
pub const ANGLE_BIN_DEG: f32 = 10.0;

/// PSNR (dB), SSIM and LPIPS averaged over some views, with their number.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeanScores {
    /// The mean scores (LPIPS NaN, `null` in JSON, below LPIPS's 31 px minimum).
    #[serde(flatten)]
    pub mean: ImageScores,
    /// Number of views averaged.
    pub views: usize,
}

impl MeanScores {
    /// The mean of `views`' scores.
    pub fn of(views: &[ImageScores]) -> Self {
        Self {
            mean: ImageScores::mean(views),
            views: views.len(),
        }
    }
}

/// The scores of the views whose |angle| falls in `[from_deg, to_deg)` (pooled over subjects).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AngleBin {
    /// Lower bound of |angle|, degrees.
    pub from_deg: f32,
    /// Upper bound of |angle| (exclusive, except the last bin), degrees.
    pub to_deg: f32,
    /// The mean scores of the bin's views.
    #[serde(flatten)]
    pub scores: MeanScores,
}

/// The breakdown by view angle: bins of |yaw| and of |pitch|.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PerAngle {
    /// Bins of |yaw|.
    pub yaw: Vec<AngleBin>,
    /// Bins of |pitch|.
    pub pitch: Vec<AngleBin>,
}

impl PerAngle {
    /// The bins of `"yaw"`, or else of pitch.
    pub fn axis(&self, axis: &str) -> &[AngleBin] {
        if axis == "yaw" {
            &self.yaw
        } else {
            &self.pitch
        }
    }
}

/// The means of the scores in the disoccluded region (the target's foreground that the source
/// view does not see, see `prism_data::Sample::disoccluded_region`), averaged like the overall scores;
/// views without such pixels, and NaN scores, are left out of the means.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DisoccludedScores {
    /// PSNR in dB in the region.
    pub psnr_disoccluded: f64,
    /// SSIM of the windows centred in the region.
    pub ssim_disoccluded: f64,
    /// LPIPS of the prediction pasted into the ground truth on the region.
    pub lpips_disoccluded: f64,
    /// PSNR over the whole image with the region taken from the ground truth: the most that
    /// any better guess in the region could add to the overall PSNR.
    pub psnr_region_filled: f64,
}

impl DisoccludedScores {
    /// The three scores as [`ImageScores`].
    pub fn scores(&self) -> ImageScores {
        ImageScores {
            psnr: self.psnr_disoccluded,
            ssim: self.ssim_disoccluded,
            lpips: self.lpips_disoccluded,
        }
    }
}

/// The scores of one way of predicting the target views (the model, its 3DGS head's render,
/// or the copy of the source view) on a set of views.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MethodScores {
    /// PSNR in dB: each subject's views averaged, then the subjects.
    pub psnr: f64,
    /// SSIM, averaged the same way.
    pub ssim: f64,
    /// LPIPS, averaged the same way.
    pub lpips: f64,
    /// Each subject's mean scores.
    pub subjects: BTreeMap<String, MeanScores>,
    /// The scores by view angle.
    pub per_angle: PerAngle,
    /// The scores in the disoccluded region, when measured (`prism evaluate`; absent from the
    /// JSON otherwise).
    #[serde(flatten)]
    pub disoccluded: Option<DisoccludedScores>,
}

impl MethodScores {
    /// The means over the subjects.
    pub fn mean(&self) -> ImageScores {
        ImageScores {
            psnr: self.psnr,
            ssim: self.ssim,
            lpips: self.lpips,
        }
    }
}

/// One scored view: its angles and scores.
#[derive(Clone)]
struct ViewScore {
    yaw: f32,
    pitch: f32,
    scores: ImageScores,
}

/// The scores of one prediction method, view by view, grouped by subject.
#[derive(Clone, Default)]
pub struct Tally {
    subjects: BTreeMap<String, Vec<ImageScores>>,
    views: Vec<ViewScore>,
    /// Each subject's scores in the disoccluded region, with the PSNR of the view whose region
    /// is filled from the ground truth.
    disoccluded: BTreeMap<String, Vec<(ImageScores, f64)>>,
}

impl Tally {
    /// Adds the scores of a batch's views: `scores[i]` is the score of the (first) target view
    /// of `samples[i]`.
    pub fn add_batch(&mut self, samples: &[Sample], scores: &[ImageScores]) {
        assert_eq!(samples.len(), scores.len(), "one score per sample");
        for (sample, &scores) in samples.iter().zip(scores) {
            let target = &sample.targets[0];
            self.subjects
                .entry(sample.subject.clone())
                .or_default()
                .push(scores);
            self.views.push(ViewScore {
                yaw: target.yaw_deg,
                pitch: target.pitch_deg,
                scores,
            });
        }
    }

    /// Adds the scores of a batch's views in their disoccluded regions and the PSNR of the
    /// views with the region filled from the ground truth
    /// ([`prism_losses::psnr_region_filled`]), as [`Tally::add_batch`].
    pub fn add_disoccluded(&mut self, samples: &[Sample], scores: &[ImageScores], filled: &[f64]) {
        assert_eq!(samples.len(), scores.len(), "one score per sample");
        assert_eq!(samples.len(), filled.len(), "one filled PSNR per sample");
        for ((sample, &scores), &filled) in samples.iter().zip(scores).zip(filled) {
            self.disoccluded
                .entry(sample.subject.clone())
                .or_default()
                .push((scores, filled));
        }
    }

    /// Each subject's views averaged, then the subjects; the views pooled by angle.
    pub fn finish(self) -> MethodScores {
        let subjects: BTreeMap<String, MeanScores> = self
            .subjects
            .into_iter()
            .map(|(name, views)| (name, MeanScores::of(&views)))
            .collect();
        let means: Vec<ImageScores> = subjects.values().map(|m| m.mean).collect();
        let ImageScores { psnr, ssim, lpips } = ImageScores::mean(&means);
        let disoccluded = (!self.disoccluded.is_empty()).then(|| {
            let subjects: Vec<(ImageScores, f64)> = self
                .disoccluded
                .values()
                .map(|views| {
                    let (scores, filled): (Vec<ImageScores>, Vec<f64>) =
                        views.iter().copied().unzip();
                    (measured_mean(&scores), mean(&filled))
                })
                .collect();
            let (scores, filled): (Vec<ImageScores>, Vec<f64>) = subjects.into_iter().unzip();
            let ImageScores { psnr, ssim, lpips } = measured_mean(&scores);
            DisoccludedScores {
                psnr_disoccluded: psnr,
                ssim_disoccluded: ssim,
                lpips_disoccluded: lpips,
                psnr_region_filled: mean(&filled),
            }
        });
        MethodScores {
            psnr,
            ssim,
            lpips,
            subjects,
            per_angle: PerAngle {
                yaw: angle_bins(&self.views, |v| v.yaw),
                pitch: angle_bins(&self.views, |v| v.pitch),
            },
            disoccluded,
        }
    }
}

/// The mean of each metric over the `scores` that measured it (not NaN); NaN when none did.
fn measured_mean(scores: &[ImageScores]) -> ImageScores {
    let mean = |f: fn(&ImageScores) -> f64| {
        let values: Vec<f64> = scores.iter().map(f).collect();
        mean(&values)
    };
    ImageScores {
        psnr: mean(|s| s.psnr),
        ssim: mean(|s| s.ssim),
        lpips: mean(|s| s.lpips),
    }
}

/// The mean of the `values` that are not NaN; NaN when all are.
fn mean(values: &[f64]) -> f64 {
    let measured: Vec<f64> = values.iter().copied().filter(|v| !v.is_nan()).collect();
    measured.iter().sum::<f64>() / measured.len() as f64
}

/// Pools the views into bins of `ANGLE_BIN_DEG` degrees of |angle|, `[from, to)`; the last bin
/// also holds its upper bound (the protocol's +-30 degree corners); empty bins are left out.
fn angle_bins(views: &[ViewScore], angle: impl Fn(&ViewScore) -> f32) -> Vec<AngleBin> {
    let top = views.iter().map(|v| angle(v).abs()).fold(0.0f32, f32::max);
    let last = ((top / ANGLE_BIN_DEG).ceil() as usize).saturating_sub(1);
    let mut bins: BTreeMap<usize, Vec<ImageScores>> = BTreeMap::new();
    for v in views {
        let k = ((angle(v).abs() / ANGLE_BIN_DEG).floor() as usize).min(last);
        bins.entry(k).or_default().push(v.scores);
    }
    bins.into_iter()
        .map(|(k, views)| AngleBin {
            from_deg: k as f32 * ANGLE_BIN_DEG,
            to_deg: (k + 1) as f32 * ANGLE_BIN_DEG,
            scores: MeanScores::of(&views),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scores(psnr: f64, ssim: f64, lpips: f64) -> ImageScores {
        ImageScores { psnr, ssim, lpips }
    }

    fn view(yaw: f32, pitch: f32, psnr: f64) -> ViewScore {
        ViewScore {
            yaw,
            pitch,
            scores: scores(psnr, 0.5, 0.1),
        }
    }

    #[test]
    fn angle_bins_pool_absolute_angles_in_ten_degree_steps() {
        let views = [
            view(-5.0, 25.0, 10.0),
            view(9.9, -30.0, 20.0),
            view(10.0, 0.0, 30.0),
            view(-30.0, 12.0, 40.0),
        ];
        let yaw = angle_bins(&views, |v| v.yaw);
        let bounds: Vec<_> = yaw.iter().map(|b| (b.from_deg, b.scores.views)).collect();
        assert_eq!(bounds, vec![(0.0, 2), (10.0, 1), (20.0, 1)]);
        assert_eq!(yaw[0].scores.mean.psnr, 15.0);
        assert_eq!(yaw[2].scores.mean.psnr, 40.0);
        let pitch = angle_bins(&views, |v| v.pitch);
        let bounds: Vec<_> = pitch.iter().map(|b| (b.from_deg, b.scores.views)).collect();
        assert_eq!(bounds, vec![(0.0, 1), (10.0, 1), (20.0, 2)]);
        assert_eq!(pitch[2].scores.mean.psnr, 15.0);
    }

    #[test]
    fn disoccluded_means_leave_out_what_was_not_measured() {
        let nan = f64::NAN;
        let m = measured_mean(&[scores(10.0, nan, 0.2), scores(20.0, 0.7, nan)]);
        assert_eq!((m.psnr, m.ssim, m.lpips), (15.0, 0.7, 0.2));
        assert!(measured_mean(&[scores(nan, nan, nan)]).psnr.is_nan());
    }

    #[test]
    fn means_average_each_metric() {
        let m = MeanScores::of(&[scores(10.0, 0.5, 0.2), scores(20.0, 0.7, 0.4)]);
        assert_eq!((m.mean.psnr, m.mean.ssim, m.views), (15.0, 0.6, 2));
        assert!((m.mean.lpips - 0.3).abs() < 1e-12);
    }
}
