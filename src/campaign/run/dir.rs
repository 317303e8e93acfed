//! The campaign directory: checking that it can hold a new campaign,
//! creating it, loading and checking an existing one against its journal, and
//! adopting a changed campaign file.

use super::*;

/// Checks that `dir` can hold a new campaign: it does not exist (its
/// parent is writable) or is an empty directory.
///
/// # Errors
/// [`CampaignRunError::BadOption`] naming `out`, the directory and the
/// reason.
pub fn check_new_dir(dir: &Path) -> Result<(), CampaignRunError> {
    let bad = |reason: String| CampaignRunError::BadOption {
        key: "out",
        value: dir.display().to_string(),
        reason,
    };
    match fs::symlink_metadata(dir) {
        Ok(m) if !m.is_dir() => Err(bad("exists and is not a directory".into())),
        Ok(_) => match fs::read_dir(dir) {
            Ok(mut it) => {
                if it.next().is_some() {
                    Err(bad(
                        "is not empty: a campaign never overwrites (use `bench campaign resume` for a campaign directory)"
                            .into(),
                    ))
                } else {
                    Ok(())
                }
            }
            Err(e) => Err(bad(format!("cannot be read: {e}"))),
        },
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            let parent = dir
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            if !parent.is_dir() {
                return Err(bad(format!(
                    "its parent {} is not a directory",
                    parent.display()
                )));
            }
            // SAFETY-free probe: access(2) on the parent for write + search.
            let c = std::ffi::CString::new(parent.as_os_str().as_encoded_bytes())
                .map_err(|_| bad("the path holds a NUL byte".into()))?;
            // SAFETY: `c` is a valid NUL-terminated path for the call.
            if unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) } != 0 {
                return Err(bad(format!(
                    "its parent {} is not writable: {}",
                    parent.display(),
                    io::Error::last_os_error()
                )));
            }
            Ok(())
        }
        Err(e) => Err(bad(e.to_string())),
    }
}

/// Creates campaign directory `dir` for `campaign`: the copies, the
/// origin, and the journal with its header. `dir` must pass
/// [`check_new_dir`].
///
/// # Errors
/// [`CampaignRunError`] if anything cannot be written (nothing is left
/// looking like a campaign then: the journal is written last).
pub fn create(campaign: &Campaign, dir: &Path) -> Result<(), CampaignRunError> {
    check_new_dir(dir)?;
    fs::create_dir_all(dir).map_err(io_at(dir))?;
    let put = |name: &str, text: &str| {
        let p = dir.join(name);
        write_atomically(&p, Existing::Refuse, |f| f.write_all(text.as_bytes())).map_err(io_at(&p))
    };
    put(CAMPAIGN_COPY, &campaign.text)?;
    put(CONFIG_COPY, &campaign.config_text)?;
    // A built-in text is named as such, not as a file here.
    let abs = |p: &Path| {
        if p == Path::new(crate::campaign::file::BUILTIN_CAMPAIGN_NAME)
            || p == Path::new(crate::config::BUILTIN_CONFIG_NAME)
        {
            return p.to_path_buf();
        }
        std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
    };
    let origin = Origin {
        campaign_file: abs(&campaign.path),
        config_file: abs(&campaign.config_path),
    };
    put(
        ORIGIN_FILE,
        &(serde_json::to_string_pretty(&origin).expect("origin serialises") + "\n"),
    )?;
    Journal::create(dir, &header_of(campaign))?;
    Ok(())
}

/// The journal header of `campaign`: its texts and their hashes.
pub(super) fn header_of(campaign: &Campaign) -> Entry {
    Entry::Header {
        version: journal::JOURNAL_VERSION,
        campaign_sha256: sha256_hex(campaign.text.as_bytes()),
        config_sha256: sha256_hex(campaign.config_text.as_bytes()),
        campaign_text: campaign.text.clone(),
        config_text: campaign.config_text.clone(),
        cells: campaign.cells().len(),
        created_utc: now_utc(),
    }
}

pub(super) fn now_utc() -> String {
    time::OffsetDateTime::now_utc()
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

/// What the journal says the campaign is now: the header's hashes and
/// texts, or those of the last `--force` resume.
pub(super) struct Current {
    pub(super) campaign_sha256: String,
    pub(super) config_sha256: String,
    pub(super) campaign_text: String,
    pub(super) config_text: String,
}

pub(super) fn current(j: &ReadJournal) -> Current {
    let mut out = Current {
        campaign_sha256: String::new(),
        config_sha256: String::new(),
        campaign_text: String::new(),
        config_text: String::new(),
    };
    for e in &j.entries {
        if let Entry::Header {
            campaign_sha256,
            config_sha256,
            campaign_text,
            config_text,
            ..
        } = e
        {
            out = Current {
                campaign_sha256: campaign_sha256.clone(),
                config_sha256: config_sha256.clone(),
                campaign_text: campaign_text.clone(),
                config_text: config_text.clone(),
            };
        }
    }
    out
}

/// Loads the campaign of directory `dir` for `resume` / `status` / `map`:
/// from the copies in `dir`, or from `campaign_file` if given. The hashes
/// must match the journal's unless `force`; a mismatch names the keys that
/// changed. Also returns a note when the original files have changed since
/// `run` (they are not used then).
///
/// # Errors
/// [`CampaignRunError::BadInput`]: not a campaign directory, a hash
/// mismatch without `force`, or an unusable campaign file.
pub fn load_dir(
    dir: &Path,
    campaign_file: Option<&Path>,
    force: bool,
) -> Result<(Campaign, ReadJournal, Option<String>), CampaignRunError> {
    let not_campaign = |why: String| {
        CampaignRunError::BadInput(format!(
            "{}: not a bench campaign directory ({why})",
            dir.display()
        ))
    };
    if !dir.is_dir() {
        return Err(not_campaign("not a directory".into()));
    }
    let j = journal::read(dir).map_err(|e| not_campaign(e.to_string()))?;
    use crate::input_file::{read_to_string, Kind};
    let copy = dir.join(CAMPAIGN_COPY);
    let copy_text =
        read_to_string(&copy, Kind::Campaign, "dir").map_err(|e| not_campaign(e.to_string()))?;
    let config_copy = dir.join(CONFIG_COPY);
    let config_copy_text = read_to_string(&config_copy, Kind::Config, "dir")
        .map_err(|e| not_campaign(e.to_string()))?;
    let was = current(&j);
    let campaign = match campaign_file {
        Some(p) => Campaign::load(p).map_err(|e| CampaignRunError::BadInput(e.to_string()))?,
        None => Campaign::from_text_with_config(&copy, copy_text.clone(), Some(&config_copy))
            .map_err(|e| CampaignRunError::BadInput(e.to_string()))?,
    };
    let mut changed = Vec::new();
    if sha256_hex(campaign.text.as_bytes()) != was.campaign_sha256 {
        changed.extend(
            changed_keys(&was.campaign_text, &campaign.text)
                .into_iter()
                .map(|k| format!("campaign {k}")),
        );
        if changed.is_empty() {
            changed.push("campaign file (comments or layout)".into());
        }
    }
    if sha256_hex(campaign.config_text.as_bytes()) != was.config_sha256 {
        let keys = changed_keys(&was.config_text, &campaign.config_text);
        if keys.is_empty() {
            changed.push("bench config (comments or layout)".into());
        }
        changed.extend(keys.into_iter().map(|k| format!("config {k}")));
    }
    if !changed.is_empty() && !force {
        return Err(CampaignRunError::BadInput(format!(
            "{}: the campaign changed since it was started ({}); resuming would mix two experiments. Pass --force to go on with the changed files (done cells at the same operating point and asymmetry are kept)",
            dir.display(),
            changed.join(", ")
        )));
    }
    // Say so when the originals changed but the copies are used.
    let mut note = None;
    if campaign_file.is_none() {
        if let Ok(text) = read_to_string(&dir.join(ORIGIN_FILE), Kind::CampaignState, "dir") {
            if let Ok(origin) = serde_json::from_str::<Origin>(&text) {
                // The originals, read as every input (one may since have
                // become a FIFO: refused, not waited on).
                let differs = |p: &Path, was: &str, kind| {
                    read_to_string(p, kind, "dir")
                        .map(|now| now != was)
                        .unwrap_or(false)
                };
                let mut which = Vec::new();
                if differs(&origin.campaign_file, &copy_text, Kind::Campaign) {
                    which.push(origin.campaign_file.display().to_string());
                }
                if differs(&origin.config_file, &config_copy_text, Kind::Config) {
                    which.push(origin.config_file.display().to_string());
                }
                if !which.is_empty() {
                    note = Some(format!(
                        "{} changed since the campaign started; it goes on with its copies in {} (pass --campaign FILE --force to use the changed files)",
                        which.join(" and "),
                        dir.display()
                    ));
                }
            }
        }
    }
    Ok((campaign, j, note))
}

/// Records in the journal (and the copies) that a forced resume goes on
/// with changed files.
///
/// # Errors
/// [`CampaignRunError`] on a write failure.
pub fn adopt_changed(
    dir: &Path,
    journal: &mut Journal,
    campaign: &Campaign,
) -> Result<(), CampaignRunError> {
    for (name, text) in [
        (CAMPAIGN_COPY, &campaign.text),
        (CONFIG_COPY, &campaign.config_text),
    ] {
        let p = dir.join(name);
        write_atomically(&p, Existing::Replace, |f| f.write_all(text.as_bytes()))
            .map_err(io_at(&p))?;
    }
    journal.append(&header_of(campaign))?;
    Ok(())
}

/// The done entry of `cell` in `j`, if one matches its coordinates.
pub(super) fn done_entry<'a>(j: &'a ReadJournal, cell: &Cell) -> Option<&'a Entry> {
    j.done().get(&cell.index).copied().filter(|e| {
        matches!(e, Entry::Done { operating_point_m, mass_asymmetry, .. }
            if *operating_point_m == cell.operating_point_m && *mass_asymmetry == cell.mass_asymmetry)
    })
}
