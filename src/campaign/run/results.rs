//! The results of a campaign directory: every cell's state from the
//! journal against the model, `cells.csv`, the map and the summary.

use super::*;

/// The state of every cell from the journal, against the model.
///
/// # Errors
/// [`CampaignRunError::BadInput`] if the model fails at a cell (cannot
/// happen for a validated campaign).
pub fn results(campaign: &Campaign, j: &ReadJournal) -> Result<Vec<CellResult>, CampaignRunError> {
    let skipped = j.skipped();
    campaign
        .cells()
        .iter()
        .map(|c| {
            let (status, verdict, reason, seed, achieved) = match done_entry(j, c) {
                Some(Entry::Done {
                    verdict,
                    reason,
                    seed,
                    achieved_mass_asymmetry,
                    ..
                }) => (
                    "done",
                    *verdict,
                    reason.clone(),
                    *seed,
                    *achieved_mass_asymmetry,
                ),
                _ if skipped.contains(&c.index) => {
                    ("skipped", None, None, campaign.seed_of(c), None)
                }
                _ => ("pending", None, None, campaign.seed_of(c), None),
            };
            let model = model_at(
                &campaign.config.plant,
                c.operating_point_m,
                achieved.unwrap_or(c.mass_asymmetry),
            )
            .map_err(|e| CampaignRunError::BadInput(e.to_string()))?;
            Ok(CellResult {
                index: c.index,
                operating_point_m: c.operating_point_m,
                mass_asymmetry: c.mass_asymmetry,
                achieved_mass_asymmetry: achieved,
                status: status.to_string(),
                verdict,
                reason,
                model_cnmp: model_cnmp_damped(&model),
                seed,
                dir: cell_dir(c.index),
            })
        })
        .collect()
}

/// Checks the files of every done cell against the journal's checksums:
/// the cells whose files are missing or changed, with the first reason.
pub fn damaged_cells(dir: &Path, j: &ReadJournal) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (cell, e) in j.done() {
        let Entry::Done { files, .. } = e else {
            continue;
        };
        for f in files {
            match file_sum(dir, &f.path) {
                Ok(now) if now == *f => {}
                Ok(_) => {
                    out.push((cell, format!("{} changed since it was recorded", f.path)));
                    break;
                }
                Err(e) => {
                    out.push((cell, format!("{}: {e}", f.path)));
                    break;
                }
            }
        }
    }
    out
}

/// The campaign summary from the journal of `dir` (no files written).
///
/// # Errors
/// As [`results`].
pub fn summarize(
    campaign: &Campaign,
    dir: &Path,
    j: &ReadJournal,
) -> Result<CampaignSummary, CampaignRunError> {
    let results = results(campaign, j)?;
    let count = |s: &str| results.iter().filter(|r| r.status == s).count();
    // Done cells against the damped model at each cell.
    let done_cells: Vec<&CellResult> = results.iter().filter(|r| r.status == "done").collect();
    let agreed = agreement(done_cells.iter().map(|r| (r.verdict, r.model_cnmp)));
    let disagreements: Vec<CellResult> = agreed
        .disagreements
        .iter()
        .map(|&i| done_cells[i].clone())
        .collect();
    let abs = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    let done = count("done");
    Ok(CampaignSummary {
        dir: abs.clone(),
        cells: results.len(),
        done,
        skipped: count("skipped"),
        pending: count("pending"),
        decided: agreed.decided,
        agree: agreed.agree,
        disagreements,
        cells_csv: abs.join(CELLS_CSV),
        map_png: (done > 0).then(|| abs.join(MAP_PNG)),
        results,
        design: None,
    })
}

/// Writes `cells.csv`, the map and `summary.json` of `dir` from its
/// journal (replacing earlier ones).
///
/// # Errors
/// [`CampaignRunError`] on a write failure.
pub fn write_results(campaign: &Campaign, dir: &Path) -> Result<CampaignSummary, CampaignRunError> {
    let j = journal::read(dir)?;
    let summary = summarize(campaign, dir, &j)?;
    let csv_path = dir.join(CELLS_CSV);
    let mut csv = String::from(
        "index,operating_point_m,mass_asymmetry,status,verdict,model_cnmp,agrees,seed,reason,recording,frf_csv,summary\n",
    );
    let done = j.done();
    for r in &summary.results {
        let verdict = r.verdict.map(|v| v.to_string()).unwrap_or_default();
        let agrees = r
            .verdict
            .map(|v| (v == r.model_cnmp).to_string())
            .unwrap_or_default();
        let reason = r
            .reason
            .clone()
            .unwrap_or_default()
            .replace(['"', ','], ";");
        // The files the done entry counts (a cell keeps what the
        // campaign's `keep` said when it ran).
        let kept: Vec<&str> = match done.get(&r.index) {
            Some(Entry::Done { files, .. }) if r.status == "done" => {
                files.iter().map(|f| f.path.as_str()).collect()
            }
            _ => Vec::new(),
        };
        let file = |i: usize| {
            let rel = format!("{}/{}", r.dir, CELL_FILES[i]);
            let named = kept
                .iter()
                .find(|p| **p == rel || (i == 0 && p.ends_with(".mcap")));
            named.map(|p| p.to_string()).unwrap_or_default()
        };
        csv.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.index,
            r.operating_point_m,
            r.mass_asymmetry,
            r.status,
            verdict,
            r.model_cnmp,
            agrees,
            r.seed,
            reason,
            file(0),
            file(1),
            file(3)
        ));
    }
    write_atomically(&csv_path, Existing::Replace, |f| {
        f.write_all(csv.as_bytes())
    })
    .map_err(io_at(&csv_path))?;
    if summary.done > 0 {
        write_map(campaign, dir, &summary)?;
    }
    let sum_path = dir.join(SUMMARY_JSON);
    let json = serde_json::to_string_pretty(&summary).expect("summaries serialise") + "\n";
    write_atomically(&sum_path, Existing::Replace, |f| {
        f.write_all(json.as_bytes())
    })
    .map_err(io_at(&sum_path))?;
    Ok(summary)
}

/// The map PNG: the damped model's CNMP map over the campaign's range
/// (half a grid step beyond each edge), the measured verdicts as squares
/// (CMP-CNMP) and circles (none), as the thesis' Fig 5-10.
pub(super) fn write_map(
    campaign: &Campaign,
    dir: &Path,
    summary: &CampaignSummary,
) -> Result<(), CampaignRunError> {
    let p = &campaign.config.plant;
    // Half a grid step beyond the outer cells, within the model's range;
    // an axis of values ≥ 0 stays ≥ 0 (the thesis' maps start there).
    let edge = |v: &[f64], lo: f64, hi: f64| {
        let (min, max) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            });
        let half = if v.len() > 1 {
            0.5 * (max - min) / (v.len() - 1) as f64
        } else {
            0.01 * (hi - lo)
        };
        let lo = if min >= 0.0 { lo.max(0.0) } else { lo };
        ((min - half).max(lo), (max + half).min(hi))
    };
    let lim = bench_plant::model::ranges::OPERATING_POINT_OF_L * p.beam.length_m;
    let (op_lo, op_hi) = edge(&campaign.operating_points_m, -lim, lim);
    let (dlo, dhi) = bench_plant::model::ranges::MASS_ASYMMETRY;
    let (dm_lo, dm_hi) = edge(&campaign.mass_asymmetries, dlo, dhi);
    let ops = linspace(op_lo, op_hi, 121);
    let dms = linspace(dm_lo, dm_hi, 91);
    let cells: Vec<MapCell> =
        cnmp_map(p, &ops, &dms).map_err(|e| CampaignRunError::BadInput(format!("map: {e}")))?;
    let measured: Vec<MeasuredPoint> = summary
        .results
        .iter()
        .filter_map(|r| {
            r.verdict.map(|v| MeasuredPoint {
                operating_point_m: r.operating_point_m,
                mass_asymmetry: r.achieved_mass_asymmetry.unwrap_or(r.mass_asymmetry),
                cnmp: v,
            })
        })
        .collect();
    let title = format!(
        "Measured verdicts ({} of {} decided, {} disagree) on the model's CNMP map",
        summary.decided,
        summary.cells,
        summary.disagreements.len()
    );
    let png = dir.join(MAP_PNG);
    write_map_png(
        &png,
        Existing::Replace,
        &title,
        p.beam.length_m,
        &ops,
        &dms,
        &cells,
        None,
        &measured,
        None,
    )
    .map_err(|e| CampaignRunError::Io {
        path: png.clone(),
        source: io::Error::other(e.to_string()),
    })
}
