//! What every dataset rendered under the viewing protocol shares, whatever its subjects are
//! made of (procedural people for `data synth`, scans for `data render`): the settings check,
//! `dataset.json`, the train / test split and per-subject seeds.

use std::path::Path;

use super::error::{DataError, Result};
use super::schema::{DatasetMeta, FORMAT_NAME, FORMAT_VERSION, Split};
use prism_core::protocol::NUM_VIEWS;

/// Smallest image size the renderer is asked for, pixels.
pub const MIN_RESOLUTION: u32 = 8;

/// Checks the settings every protocol dataset has: the resolution (at least
/// [`MIN_RESOLUTION`]), the test fraction (in `[0, 1]`) and the background (components in
/// `[0, 1]`); errors name `out`.
pub fn check_settings(
    out: &Path,
    resolution: u32,
    test_fraction: f32,
    background: [f32; 3],
) -> Result<()> {
    if resolution < MIN_RESOLUTION {
        return Err(DataError::invalid(
            out,
            format!("the resolution must be at least {MIN_RESOLUTION} px, got {resolution}"),
        ));
    }
    if !(0.0..=1.0).contains(&test_fraction) {
        return Err(DataError::invalid(
            out,
            format!("the test fraction must be in [0, 1], got {test_fraction}"),
        ));
    }
    if background.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(DataError::invalid(
            out,
            "background components must be in [0, 1]",
        ));
    }
    Ok(())
}

/// The train / test split of `names` (in their order): the last `round(n * test_fraction)` are
/// held out, at least one and at most `n - 1` when the fraction is positive and below 1 (none
/// with a single subject). A fraction of 1 holds out every subject: a test-only dataset, such
/// as scans from another domain to evaluate a trained model on.
pub fn split_last(names: &[String], test_fraction: f32) -> Split {
    let n = names.len();
    let test = if test_fraction >= 1.0 {
        n
    } else if test_fraction > 0.0 && n >= 2 {
        ((n as f32 * test_fraction).round() as usize).clamp(1, n - 1)
    } else {
        0
    };
    Split {
        train: names[..n - test].to_vec(),
        test: names[n - test..].to_vec(),
    }
}

/// The `dataset.json` of a square protocol dataset (105 views per subject) of `subjects`,
/// split by [`split_last`]; `generator` records how it was made.
pub fn protocol_meta(
    resolution: u32,
    background: [f32; 3],
    subjects: Vec<String>,
    test_fraction: f32,
    generator: serde_json::Value,
) -> DatasetMeta {
    DatasetMeta {
        format: FORMAT_NAME.into(),
        version: FORMAT_VERSION,
        width: resolution,
        height: resolution,
        background,
        views: NUM_VIEWS,
        split: split_last(&subjects, test_fraction),
        subjects,
        generator,
    }
}

/// A seed for item `key` of a dataset seeded with `seed`: one SplitMix64 step, so that nearby
/// seeds and keys give unrelated draws.
pub fn keyed_seed(seed: u64, key: u64) -> u64 {
    let mut z = seed.wrapping_add(key.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The seed of the subject called `name` in a dataset seeded with `seed`: it depends on the
/// name only (FNV-1a of its bytes), not on which other subjects exist, so reruns and added
/// subjects leave every subject's draw unchanged.
pub fn named_seed(seed: u64, name: &str) -> u64 {
    let hash = name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    });
    keyed_seed(seed, hash)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(n: usize) -> Vec<String> {
        (0..n).map(|i| format!("s{i}")).collect()
    }

    #[test]
    fn split_holds_out_the_last_subjects() {
        let s = split_last(&names(8), 0.125);
        assert_eq!(s.test, vec!["s7"]);
        assert_eq!(s.train.len(), 7);
        assert_eq!(split_last(&names(3), 0.1).test.len(), 1, "at least one");
        assert!(
            split_last(&names(1), 0.5).test.is_empty(),
            "a single subject trains"
        );
        assert_eq!(split_last(&names(4), 0.9).train.len(), 1, "one trains");
        assert!(split_last(&names(5), 0.0).test.is_empty());
        assert_eq!(
            split_last(&names(1), 1.0).test,
            vec!["s0"],
            "1 holds out all"
        );
        assert!(split_last(&names(3), 1.0).train.is_empty());
        assert_eq!(split_last(&[], 0.5), Split::default());
    }

    #[test]
    fn seeds_differ_by_key_name_and_seed() {
        let seeds: std::collections::HashSet<u64> = (0..100).map(|i| keyed_seed(0, i)).collect();
        assert_eq!(seeds.len(), 100);
        assert_ne!(keyed_seed(0, 1), keyed_seed(1, 1));
        assert_eq!(named_seed(3, "0001"), named_seed(3, "0001"));
        assert_ne!(named_seed(3, "0001"), named_seed(3, "0002"));
        assert_ne!(named_seed(3, "0001"), named_seed(4, "0001"));
    }

    #[test]
    fn settings_are_checked_and_named() {
        let out = Path::new("ds");
        assert!(check_settings(out, 32, 0.1, [1.0; 3]).is_ok());
        assert!(check_settings(out, 32, 1.0, [1.0; 3]).is_ok(), "test-only");
        for (res, f, bg) in [
            (4, 0.1, [1.0; 3]),
            (32, 1.5, [1.0; 3]),
            (32, -0.1, [1.0; 3]),
            (32, 0.1, [2.0, 0.0, 0.0]),
        ] {
            let e = check_settings(out, res, f, bg).unwrap_err().to_string();
            assert!(e.starts_with("ds: "), "{e}");
        }
    }
}
