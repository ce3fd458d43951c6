//! The reference pairs of `tests/reference/` reproduced: PSNR to 1e-6, SSIM to 1e-4, LPIPS to
//! 1e-3 (see `tests/reference/README.md` for where the values come from), on ndarray and flex.

use std::path::{Path, PathBuf};

use burn::tensor::Device;
use prism_core::BackendKind;
use prism_losses::{Lpips, load_image, score_files, ssim};

fn reference_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference")
}

fn references() -> Vec<(String, f64, f64, f64)> {
    let text = std::fs::read_to_string(reference_dir().join("reference.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut out: Vec<_> = json
        .as_object()
        .unwrap()
        .iter()
        .map(|(name, v)| {
            (
                name.clone(),
                v["psnr"].as_f64().unwrap(),
                v["ssim"].as_f64().unwrap(),
                v["lpips_alex"].as_f64().unwrap(),
            )
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

fn check_backend(device: &Device) {
    let lpips = Lpips::load_default(None, device).unwrap();
    let refs = references();
    assert_eq!(refs.len(), 2);
    for (name, psnr, ssim, lpips_ref) in refs {
        let dir = reference_dir();
        let scores = score_files(
            &dir.join(format!("{name}_pred.png")),
            &dir.join(format!("{name}_target.png")),
            &lpips,
            device,
        )
        .unwrap();
        assert!(
            (scores.psnr - psnr).abs() < 1e-6,
            "{name}: PSNR {} vs {psnr}",
            scores.psnr
        );
        assert!(
            (scores.ssim - ssim).abs() < 1e-4,
            "{name}: SSIM {} vs {ssim}",
            scores.ssim
        );
        assert!(
            (scores.lpips - lpips_ref).abs() < 1e-3,
            "{name}: LPIPS {} vs {lpips_ref}",
            scores.lpips
        );
        eprintln!(
            "{name}: dPSNR {:.2e} dSSIM {:.2e} dLPIPS {:.2e}",
            scores.psnr - psnr,
            scores.ssim - ssim,
            scores.lpips - lpips_ref
        );
    }
}

#[test]
fn reference_pairs_on_ndarray() {
    check_backend(&BackendKind::Ndarray.device().unwrap());
}

#[test]
fn reference_pairs_on_flex() {
    check_backend(&BackendKind::Flex.device().unwrap());
}

#[test]
fn ssim_of_an_image_with_itself_is_one() {
    let device = BackendKind::Ndarray.device().unwrap();
    let image = load_image(&reference_dir().join("coffee_tint_target.png"), &device).unwrap();
    let values = ssim(image.clone(), image);
    assert_eq!(values.len(), 1);
    assert!((values[0] - 1.0).abs() < 1e-6, "SSIM(x, x) = {}", values[0]);
}

#[test]
fn metrics_are_per_image_in_a_batch() {
    let device = BackendKind::Ndarray.device().unwrap();
    let dir = reference_dir();
    let pred = load_image(&dir.join("coffee_tint_pred.png"), &device).unwrap();
    let gt = load_image(&dir.join("coffee_tint_target.png"), &device).unwrap();
    // Image 0: the reference pair; image 1: the target against itself plus 0.1 (PSNR 20 dB).
    let batch_pred = burn::tensor::Tensor::cat(vec![pred.clone(), gt.clone().add_scalar(0.1)], 0);
    let batch_gt = burn::tensor::Tensor::cat(vec![gt.clone(), gt.clone()], 0);
    let p = prism_losses::psnr(batch_pred.clone(), batch_gt.clone());
    let s = ssim(batch_pred, batch_gt);
    assert_eq!((p.len(), s.len()), (2, 2));
    assert!((p[0] - prism_losses::psnr(pred.clone(), gt.clone())[0]).abs() < 1e-9);
    assert!((p[1] - 20.0).abs() < 1e-4, "PSNR of a 0.1 offset: {}", p[1]);
    assert!((s[0] - ssim(pred, gt)[0]).abs() < 1e-9);
    // Structure and contrast are unchanged by an offset; luminance drops (a dark image).
    assert!(
        s[1] < 0.99 && s[1] > 0.5,
        "SSIM of a small offset: {}",
        s[1]
    );
}
