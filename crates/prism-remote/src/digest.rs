//! The digest of a dataset: what a trainer and a served device compare to know that they hold
//! the same dataset ([`crate::handshake`]), and what long jobs store with each of their results
//! (`prism_train::Provenance`).
//!
//! It is the BLAKE3 hash of the dataset's `dataset.json` and, for every file (hidden names left
//! out), of its path, its size and the BLAKE3 hash of its contents: any edit changes it, one
//! that keeps every file's length included. Hashing gigabytes takes seconds, so each file's hash
//! is kept in [`CACHE_FILE`], in the dataset's folder, under its path, size and modification
//! time; a rerun hashes only the files whose size or time changed. What it cannot see: an edit
//! that keeps a file's size and sets its modification time back (`make` and `rsync` miss it
//! too). A file modified less than [`SETTLE`] before its hashing began is hashed again on every
//! run, so that a second edit within the file system's timestamp resolution, which can keep the
//! time, is seen. A dataset folder this process cannot write to is hashed whole every time.

use std::collections::BTreeMap;
use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use prism_data::DatasetReader;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The cache of the files' hashes, in the dataset's folder (a hidden name: not part of the
/// dataset, nor of its digest).
pub const CACHE_FILE: &str = ".prism-digests.json";

/// How long before its hashing began a file must have been modified for its hash to be cached:
/// more than the coarsest timestamp resolution of common file systems (2 s, FAT).
pub const SETTLE: Duration = Duration::from_secs(3);

/// The cache's `format` field; a cache of another format (or none, or a malformed one) is
/// ignored and rewritten.
const CACHE_FORMAT: &str = "prism-digests-v1";

/// The digest of the dataset opened by `reader` (64 hexadecimal digits): equal digests, the
/// same `dataset.json` and the same files with the same contents. The hashes of its files are
/// cached in [`CACHE_FILE`] (see the module docs).
///
/// # Errors
/// A folder of the dataset that cannot be listed or a file that cannot be read, naming it.
pub fn dataset_digest(reader: &DatasetReader) -> io::Result<String> {
    let meta = serde_json::to_string(reader.meta()).expect("a dataset's meta serialises");
    let started = SystemTime::now();
    let mut files = Vec::new();
    list_files(reader.root(), reader.root(), &mut files)?;
    files.sort_by(|a, b| a.name.cmp(&b.name));
    let cache_path = reader.root().join(CACHE_FILE);
    let cached = read_cache(&cache_path);
    let hashes = files
        .par_iter()
        .map(|file| match cached.get(&file.name) {
            Some(entry) if Some(entry.modified) == file.modified && entry.size == file.size => {
                Ok(entry.blake3.clone())
            }
            _ => hash_file(&file.path),
        })
        .collect::<io::Result<Vec<String>>>()?;
    let mut digest = blake3::Hasher::new();
    digest.update(meta.as_bytes());
    for (file, hash) in files.iter().zip(&hashes) {
        digest.update(format!("\n{}\t{}\t{hash}", file.name, file.size).as_bytes());
    }
    let settled = |stamp: Stamp| {
        let modified = UNIX_EPOCH + Duration::new(stamp.secs, stamp.nanos);
        started
            .duration_since(modified)
            .is_ok_and(|age| age >= SETTLE)
    };
    let fresh: BTreeMap<String, Entry> = files
        .iter()
        .zip(hashes)
        .filter_map(|(file, blake3)| {
            let modified = file.modified.filter(|&m| settled(m))?;
            let entry = Entry {
                size: file.size,
                modified,
                blake3,
            };
            Some((file.name.clone(), entry))
        })
        .collect();
    if fresh != cached {
        let cache = Cache {
            format: CACHE_FORMAT.to_string(),
            files: fresh,
        };
        // Compact JSON: a dataset of many files has a long cache. One that cannot be written
        // (a read-only dataset) only costs the next run time: the digest is right all the same.
        let _ = prism_core::files::write_atomic(&cache_path, |out| {
            serde_json::to_writer(out, &cache).map_err(io::Error::other)
        });
    }
    Ok(digest.finalize().to_hex().to_string())
}

/// A file of the dataset.
struct Listed {
    /// Where it is.
    path: PathBuf,
    /// Its path relative to the dataset's folder, with `/` separators.
    name: String,
    /// Bytes.
    size: u64,
    /// When it was last modified (`None` where the system cannot say, or before 1970).
    modified: Option<Stamp>,
}

/// A modification time: seconds and nanoseconds since 1970.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
struct Stamp {
    secs: u64,
    nanos: u32,
}

impl Stamp {
    fn of(time: SystemTime) -> Option<Self> {
        let since = time.duration_since(UNIX_EPOCH).ok()?;
        Some(Self {
            secs: since.as_secs(),
            nanos: since.subsec_nanos(),
        })
    }
}

/// The cached hash of one file, valid while its size and modification time are these.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
struct Entry {
    size: u64,
    modified: Stamp,
    /// BLAKE3 of the contents, hexadecimal.
    blake3: String,
}

/// [`CACHE_FILE`]: the cached hashes, by the files' relative paths.
#[derive(Serialize, Deserialize)]
struct Cache {
    format: String,
    files: BTreeMap<String, Entry>,
}

/// The entries of the cache at `path`; none where it is missing, malformed or of another format.
fn read_cache(path: &Path) -> BTreeMap<String, Entry> {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|text| serde_json::from_str::<Cache>(&text).ok())
        .filter(|cache| cache.format == CACHE_FORMAT)
        .map(|cache| cache.files)
        .unwrap_or_default()
}

/// `e` (of the same kind) naming `path`.
fn named(e: io::Error, path: &Path) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// The BLAKE3 hash of the contents of the file at `path`, hexadecimal.
fn hash_file(path: &Path) -> io::Result<String> {
    let file = File::open(path).map_err(|e| named(e, path))?;
    let mut hasher = blake3::Hasher::new();
    hasher.update_reader(file).map_err(|e| named(e, path))?;
    Ok(hasher.finalize().to_hex().to_string())
}

/// Appends the files under `dir` (recursively, through links, hidden names left out) to `out`.
fn list_files(root: &Path, dir: &Path, out: &mut Vec<Listed>) -> io::Result<()> {
    for entry in std::fs::read_dir(dir).map_err(|e| named(e, dir))? {
        let entry = entry.map_err(|e| named(e, dir))?;
        if entry.file_name().to_string_lossy().starts_with('.') {
            continue;
        }
        let path = entry.path();
        let meta = std::fs::metadata(&path).map_err(|e| named(e, &path))?;
        if meta.is_dir() {
            list_files(root, &path, out)?;
        } else {
            let relative = path.strip_prefix(root).unwrap_or(&path);
            let parts: Vec<String> = relative
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            out.push(Listed {
                name: parts.join("/"),
                size: meta.len(),
                modified: meta.modified().ok().and_then(Stamp::of),
                path,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_data::DatasetMeta;
    use prism_data::schema::{FORMAT_NAME, FORMAT_VERSION};

    const HOUR: Duration = Duration::from_secs(3600);

    /// Writes `bytes` to `root/name`, modified `age` ago.
    fn write_aged(root: &Path, name: &str, bytes: &[u8], age: Duration) {
        let path = root.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, bytes).unwrap();
        set_modified(&path, SystemTime::now() - age);
    }

    fn set_modified(path: &Path, time: SystemTime) {
        File::options()
            .write(true)
            .open(path)
            .unwrap()
            .set_modified(time)
            .unwrap();
    }

    fn modified(path: &Path) -> SystemTime {
        std::fs::metadata(path).unwrap().modified().unwrap()
    }

    /// A dataset of no subjects holding `files` (name, contents), all modified an hour ago.
    fn dataset(files: &[(&str, &[u8])]) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let meta = DatasetMeta {
            format: FORMAT_NAME.to_string(),
            version: FORMAT_VERSION,
            width: 4,
            height: 4,
            background: [0.0; 3],
            views: 1,
            subjects: Vec::new(),
            split: Default::default(),
            generator: serde_json::Value::Null,
        };
        let json = serde_json::to_vec(&meta).unwrap();
        write_aged(dir.path(), "dataset.json", &json, HOUR);
        for (name, bytes) in files {
            write_aged(dir.path(), name, bytes, HOUR);
        }
        dir
    }

    fn digest(dir: &Path) -> String {
        dataset_digest(&DatasetReader::open(dir).unwrap()).unwrap()
    }

    #[test]
    fn an_edit_that_keeps_every_length_changes_the_digest() {
        let data = dataset(&[("points/000.npy", &[1; 64])]);
        let before = digest(data.path());
        write_aged(data.path(), "points/000.npy", &[2; 64], HOUR / 2);
        assert_ne!(digest(data.path()), before);
    }

    #[test]
    fn a_rerun_hashes_only_the_files_whose_size_or_time_changed() {
        let data = dataset(&[("a.npy", &[1; 64]), ("b.npy", &[3; 64])]);
        let (a, b) = (data.path().join("a.npy"), data.path().join("b.npy"));
        let first = digest(data.path());
        let cache = read_cache(&data.path().join(CACHE_FILE));
        assert_eq!(
            cache.keys().collect::<Vec<_>>(),
            ["a.npy", "b.npy", "dataset.json"]
        );
        // New contents behind the cache's back (the same size, the time set back): the rerun
        // takes the cached hash and does not read the file.
        let when = modified(&a);
        std::fs::write(&a, [9; 64]).unwrap();
        set_modified(&a, when);
        assert_eq!(digest(data.path()), first, "the cache was not used");
        // A new time: read again, as a run without the cache reads it.
        set_modified(&a, when + Duration::from_secs(1));
        let changed = digest(data.path());
        assert_ne!(changed, first);
        std::fs::remove_file(data.path().join(CACHE_FILE)).unwrap();
        assert_eq!(digest(data.path()), changed);
        // A new size, the same time: read again.
        let when = modified(&b);
        std::fs::write(&b, [3; 65]).unwrap();
        set_modified(&b, when);
        assert_ne!(digest(data.path()), changed);
    }

    #[test]
    fn files_modified_just_now_are_read_on_every_run() {
        let data = dataset(&[]);
        let fresh = data.path().join("fresh.npy");
        std::fs::write(&fresh, [1; 64]).unwrap();
        let first = digest(data.path());
        assert!(!read_cache(&data.path().join(CACHE_FILE)).contains_key("fresh.npy"));
        // Rewritten within the timestamp resolution, its time unchanged: still seen.
        let when = modified(&fresh);
        std::fs::write(&fresh, [2; 64]).unwrap();
        set_modified(&fresh, when);
        assert_ne!(digest(data.path()), first);
    }
}
