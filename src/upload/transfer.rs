//! One file to the store and its confirmation: what a recording's upload
//! consists of ([`upload_set`]) and how one item goes up ([`transfer`]).

use super::store::{classify, ProbeError, Store, StoreUrl};
use super::{MULTIPART_THRESHOLD_BYTES, PART_BYTES};
use crate::catalogue::file::write_rows;
use crate::catalogue::{row_of_recording, CATALOGUE_DIR};
use futures_util::StreamExt;
use object_store::{ObjectStoreExt, PutPayload, WriteMultipart};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::io::Read;
use std::path::{Path, PathBuf};

/// Where an item's bytes come from.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// A local file, as it is.
    File(PathBuf),
    /// The catalogue row of `recording` ([`row_of_recording`]), its
    /// `recording` column set to `recording_url` (the recording's object):
    /// built when it is uploaded, from the recording alone, so it is the
    /// same row every time.
    CatalogueRow {
        /// The finished recording.
        recording: PathBuf,
        /// Its object's URL.
        recording_url: String,
    },
}

/// One object to upload: its key under the store's root and its source.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Item {
    /// The object's key (the store's prefix included).
    pub key: String,
    /// Where its bytes come from.
    pub source: Source,
}

/// What a recording's upload consists of, in order: the recording
/// `DIR/STEM.mcap`, every regular file `DIR/STEM.*` beside it (its FRF
/// CSV, plots, summary; never a `.part` or a temporary file), and its
/// catalogue row (`catalogue/STEM.parquet`, whose `recording` is the
/// recording's object URL), each under the store's prefix by its name.
///
/// # Errors
/// Why `recording` is not a finished recording of `bench` (a `.part`, a
/// file that is not MCAP, one without `bench`'s metadata, a missing file).
pub fn upload_set(url: &StoreUrl, recording: &Path) -> Result<Vec<Item>, String> {
    let name = recording
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let Some(stem) = name.strip_suffix(".mcap") else {
        return Err(format!(
            "{} is not a finished recording (a recording's name ends in .mcap; a .part is a run still running or killed: `bench recover` it first)",
            recording.display()
        ));
    };
    check_name(&name)?;
    row_of_recording(recording).map_err(|e| crate::error::error_chain(&e))?;
    let recording = std::path::absolute(recording).map_err(|e| e.to_string())?;
    let dir = recording.parent().unwrap_or(Path::new("/")).to_path_buf();
    let key = url.key_of(&name);
    let recording_url = url.object_url(&key);
    let mut items = vec![Item {
        key,
        source: Source::File(recording.clone()),
    }];
    let mut siblings = Vec::new();
    let with_dot = format!("{stem}.");
    for entry in std::fs::read_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))? {
        let entry = entry.map_err(|e| format!("{}: {e}", dir.display()))?;
        let n = entry.file_name().to_string_lossy().into_owned();
        if n == name
            || !n.starts_with(&with_dot)
            || n.ends_with(crate::outputs::PART_SUFFIX)
            || n.ends_with(".tmp")
            || !entry.file_type().is_ok_and(|t| t.is_file())
        {
            continue;
        }
        check_name(&n)?;
        siblings.push(n);
    }
    siblings.sort();
    items.extend(siblings.into_iter().map(|n| Item {
        key: url.key_of(&n),
        source: Source::File(dir.join(&n)),
    }));
    items.push(Item {
        key: url.key_of(&format!("{CATALOGUE_DIR}/{stem}.parquet")),
        source: Source::CatalogueRow {
            recording,
            recording_url,
        },
    });
    Ok(items)
}

/// What a path's upload consists of: a campaign directory's
/// ([`campaign_upload_set`]) or a recording's ([`upload_set`]).
///
/// # Errors
/// As those: not a finished recording, not a campaign directory, or a
/// name a store cannot keep.
pub fn upload_set_of(url: &StoreUrl, path: &Path) -> Result<Vec<Item>, String> {
    if path.is_dir() {
        campaign_upload_set(url, path)
    } else {
        upload_set(url, path)
    }
}

/// How deep a campaign directory's files are looked for
/// (`cells/NNN/chirp.mcap` is 2 below it).
const CAMPAIGN_DEPTH: usize = 4;

/// What a campaign directory's (or a track run's directory's) upload
/// consists of: every regular file
/// below it (its cells' kept files, `cells.csv`, `summary.json`, the map,
/// the journal, its copy of the campaign and bench files, its catalogue
/// rows; never a `.part`, a temporary or hidden file, or a link), each
/// under the store's prefix as `CAMPAIGN/RELATIVE PATH`, CAMPAIGN being
/// the directory's name. A cell's row whose recording was kept goes up
/// with `recording` set to the recording's object URL (as a recording's
/// row, [`Source::CatalogueRow`]); the row of a cell whose recording was
/// not kept goes up as it is (`recording` null). The cells' files first,
/// then the rows, then the campaign's own files.
///
/// # Errors
/// `dir` is not a campaign directory (no `journal.jsonl`) nor a track
/// run's (no [`crate::jobs::track::TRACK_SUMMARY_FILE`]: it uploads as
/// a campaign's, without catalogue rows), cannot be
/// read, or holds a name a store cannot keep.
pub fn campaign_upload_set(url: &StoreUrl, dir: &Path) -> Result<Vec<Item>, String> {
    use crate::jobs::track::TRACK_SUMMARY_FILE;
    let dir = std::path::absolute(dir).map_err(|e| e.to_string())?;
    if !dir.join(crate::catalogue::CAMPAIGN_JOURNAL_FILE).is_file()
        && !dir.join(TRACK_SUMMARY_FILE).is_file()
    {
        return Err(format!(
            "{} is not a campaign directory (no {}), a track run's directory (no {TRACK_SUMMARY_FILE}) nor a finished recording",
            dir.display(),
            crate::catalogue::CAMPAIGN_JOURNAL_FILE
        ));
    }
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    check_name(&name)?;
    let mut files = Vec::new();
    collect_files(&dir, Path::new(""), 0, &mut files)?;
    // Cells, then rows, then the campaign's own files; by path within.
    let rank = |rel: &Path| match rel.components().next() {
        Some(c) if c.as_os_str() == crate::catalogue::CAMPAIGN_CELLS_DIR => 0,
        Some(c) if c.as_os_str() == CATALOGUE_DIR && rel.components().count() == 2 => 1,
        _ => 2,
    };
    files.sort_by(|a, b| (rank(a), a).cmp(&(rank(b), b)));
    let key_of = |rel: &Path| {
        let segs: Vec<String> = rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        url.key_of(&format!("{name}/{}", segs.join("/")))
    };
    let mut items = Vec::with_capacity(files.len());
    for rel in files {
        let key = key_of(&rel);
        let cell_recording = (rank(&rel) == 1)
            .then(|| crate::catalogue::cell_recording_of_row(rel.file_name()?.to_str()?))
            .flatten()
            .filter(|r| dir.join(r).is_file());
        let source = match cell_recording {
            Some(r) => Source::CatalogueRow {
                recording: dir.join(&r),
                recording_url: url.object_url(&key_of(&r)),
            },
            None => Source::File(dir.join(&rel)),
        };
        items.push(Item { key, source });
    }
    Ok(items)
}

/// The regular files below `root.join(rel)` (paths relative to `root`).
fn collect_files(
    root: &Path,
    rel: &Path,
    depth: usize,
    out: &mut Vec<PathBuf>,
) -> Result<(), String> {
    let dir = root.join(rel);
    let entries = std::fs::read_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries {
        let entry = entry.map_err(|e| format!("{}: {e}", dir.display()))?;
        let n = entry.file_name().to_string_lossy().into_owned();
        let Ok(t) = entry.file_type() else { continue };
        if n.starts_with('.') || n.ends_with(crate::outputs::PART_SUFFIX) || n.ends_with(".tmp") {
            continue;
        }
        if t.is_file() {
            check_name(&n)?;
            out.push(rel.join(&n));
        } else if t.is_dir() && depth < CAMPAIGN_DEPTH {
            check_name(&n)?;
            collect_files(root, &rel.join(&n), depth + 1, out)?;
        }
    }
    Ok(())
}

/// A file name every store keeps as it is, and its URL too: ASCII letters,
/// digits, `-`, `_` and `.` (`bench`'s own names are). A directory store
/// (`object_store`'s local file system) would encode other characters in
/// the file's name, and a URL encodes them in its own way.
fn check_name(name: &str) -> Result<(), String> {
    match name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || "-_.".contains(*c)))
    {
        None => Ok(()),
        Some(c) => Err(format!(
            "{name:?}: {c:?} cannot be in the name of a file that is uploaded (ASCII letters, digits, -, _ and . only, as bench names its recordings): rename it"
        )),
    }
}

/// An item the store confirmed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Transferred {
    /// The object's key.
    pub key: String,
    /// Its URL.
    pub url: String,
    /// Its size, bytes.
    pub size_bytes: u64,
    /// The SHA-256 (hex) of the local bytes, equal to the object's as read
    /// back from the store.
    pub sha256: String,
    /// `true`: uploaded now; `false`: already in the store with the same
    /// checksum (not uploaded again).
    pub uploaded: bool,
}

/// Why an item did not go up.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TransferError {
    /// The store failed or did not answer: tried again later.
    #[error("{0}")]
    Retry(String),
    /// The item cannot go up (its local file is gone, an object of the
    /// same name holds other contents): dropped from the queue, the local
    /// file kept.
    #[error("{0}")]
    Drop(String),
}

/// The local bytes of an item: a file (read as it goes up) or a built row.
enum Local {
    File(PathBuf, u64),
    Bytes(Vec<u8>),
}

fn local_of(source: &Source) -> Result<Local, TransferError> {
    match source {
        Source::File(p) => match std::fs::metadata(p) {
            Ok(m) if m.is_file() => Ok(Local::File(p.clone(), m.len())),
            Ok(_) => Err(TransferError::Drop(format!(
                "{} is no longer a regular file",
                p.display()
            ))),
            Err(e) => Err(TransferError::Drop(format!("{}: {e}", p.display()))),
        },
        Source::CatalogueRow {
            recording,
            recording_url,
        } => {
            let mut row = row_of_recording(recording)
                .map_err(|e| TransferError::Drop(crate::error::error_chain(&e)))?;
            row.recording = Some(recording_url.clone());
            let mut buf = Vec::new();
            write_rows(std::slice::from_ref(&row), &mut buf)
                .map_err(|e| TransferError::Drop(format!("the catalogue row: {e}")))?;
            Ok(Local::Bytes(buf))
        }
    }
}

fn hex(d: &[u8]) -> String {
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 and size of the local bytes.
fn local_digest(local: &Local) -> Result<(u64, String), TransferError> {
    match local {
        Local::Bytes(b) => Ok((b.len() as u64, hex(&Sha256::digest(b)))),
        Local::File(p, _) => {
            let gone = |e: std::io::Error| TransferError::Drop(format!("{}: {e}", p.display()));
            let mut f = std::fs::File::open(p).map_err(gone)?;
            let mut h = Sha256::new();
            let mut buf = vec![0u8; 1 << 20];
            let mut n_total = 0u64;
            loop {
                let n = f.read(&mut buf).map_err(gone)?;
                if n == 0 {
                    break;
                }
                n_total += n as u64;
                h.update(&buf[..n]);
            }
            Ok((n_total, hex(&h.finalize())))
        }
    }
}

fn store_error(what: &str, e: &object_store::Error) -> TransferError {
    TransferError::Retry(match classify(e) {
        ProbeError::Refused(m) | ProbeError::Unreachable(m) => format!("{what}: {m}"),
    })
}

/// SHA-256 and size of the object at `key`, read back from the store.
async fn remote_digest(store: &Store, key: &str) -> Result<(u64, String), TransferError> {
    let get = store
        .within(store.inner.get(&Store::path(key)))
        .await
        .map_err(|e| store_error("reading the object back", &e))?;
    let mut stream = get.into_stream();
    let mut h = Sha256::new();
    let mut n = 0u64;
    // Each read is given the store's timeout (a store that stops sending).
    while let Some(chunk) = store
        .within(async { stream.next().await.transpose() })
        .await
        .transpose()
    {
        let chunk = chunk.map_err(|e| store_error("reading the object back", &e))?;
        n += chunk.len() as u64;
        h.update(&chunk);
    }
    Ok((n, hex(&h.finalize())))
}

/// Puts the bytes of `local` at `key`: one PUT, or a multipart upload for
/// a file over [`MULTIPART_THRESHOLD_BYTES`] (aborted on an error).
async fn put(store: &Store, key: &str, local: &Local) -> Result<(), TransferError> {
    let path = Store::path(key);
    match local {
        Local::Bytes(b) => {
            store
                .within(store.inner.put(&path, PutPayload::from(b.clone())))
                .await
                .map_err(|e| store_error("uploading", &e))?;
        }
        Local::File(p, size) if *size <= MULTIPART_THRESHOLD_BYTES => {
            let bytes = std::fs::read(p)
                .map_err(|e| TransferError::Drop(format!("{}: {e}", p.display())))?;
            store
                .within(store.inner.put(&path, PutPayload::from(bytes)))
                .await
                .map_err(|e| store_error("uploading", &e))?;
        }
        Local::File(p, _) => {
            let gone = |e: std::io::Error| TransferError::Drop(format!("{}: {e}", p.display()));
            let upload = store
                .within(store.inner.put_multipart(&path))
                .await
                .map_err(|e| store_error("starting the multipart upload", &e))?;
            let mut w = WriteMultipart::new_with_chunk_size(upload, PART_BYTES);
            let mut f = std::fs::File::open(p).map_err(gone)?;
            let mut buf = vec![0u8; PART_BYTES];
            loop {
                let mut filled = 0;
                while filled < buf.len() {
                    match f.read(&mut buf[filled..]) {
                        Ok(0) => break,
                        Ok(n) => filled += n,
                        Err(e) => {
                            let _ = w.abort().await;
                            return Err(gone(e));
                        }
                    }
                }
                if filled == 0 {
                    break;
                }
                if let Err(e) = w.wait_for_capacity(2).await {
                    let _ = w.abort().await;
                    return Err(store_error("uploading a part", &e));
                }
                w.write(&buf[..filled]);
                if filled < buf.len() {
                    break;
                }
            }
            w.finish()
                .await
                .map_err(|e| store_error("completing the multipart upload", &e))?;
        }
    }
    Ok(())
}

/// Uploads `item` unless the store holds it already, and confirms it by
/// reading the object back: its size and SHA-256 must equal the local
/// bytes'. An object that differs after the upload is deleted and the
/// item retried.
///
/// # Errors
/// [`TransferError::Retry`] when the store fails or does not answer;
/// [`TransferError::Drop`] when the local file is gone or the store holds
/// another object of the same name.
pub async fn transfer(store: &Store, item: &Item) -> Result<Transferred, TransferError> {
    let local = local_of(&item.source)?;
    let (size_bytes, sha256) = local_digest(&local)?;
    let confirmed = |uploaded| Transferred {
        key: item.key.clone(),
        url: store.url.object_url(&item.key),
        size_bytes,
        sha256: sha256.clone(),
        uploaded,
    };
    match store
        .within(store.inner.head(&Store::path(&item.key)))
        .await
    {
        Ok(meta) => {
            if meta.size == size_bytes && remote_digest(store, &item.key).await?.1 == sha256 {
                return Ok(confirmed(false));
            }
            return Err(TransferError::Drop(format!(
                "{} already holds another object ({} bytes); it is not overwritten",
                store.url.object_url(&item.key),
                meta.size
            )));
        }
        Err(object_store::Error::NotFound { .. }) => {}
        Err(e) => return Err(store_error("asking for the object", &e)),
    }
    put(store, &item.key, &local).await?;
    let (n, sum) = remote_digest(store, &item.key).await?;
    if n != size_bytes || sum != sha256 {
        let _ = store
            .within(store.inner.delete(&Store::path(&item.key)))
            .await;
        return Err(TransferError::Retry(format!(
            "the object read back ({n} bytes, SHA-256 {sum}) differs from the local file ({size_bytes} bytes, {sha256}); deleted, to be uploaded again"
        )));
    }
    Ok(confirmed(true))
}
