//! The two updates: to measured natural frequencies, and to a measured FRF
//! (from the fitted modes first, then on the FRF itself).

use super::*;

/// Updates the free parameters of `start` to measured natural
/// frequencies `measured_hz` (ascending, at most four), step 1 of the
/// [module docs](super).
///
/// # Errors
/// [`UpdateError`]: nothing free, a free parameter the frequencies do not
/// determine, fewer frequencies than free parameters or more than four, a
/// start that is no bench, or no fit.
pub fn update_to_frequencies(
    start: &Bench,
    free: &[Parameter],
    measured_hz: &[f64],
) -> Result<Update, UpdateError> {
    if free.is_empty() {
        return Err(UpdateError::NoFreeParameter);
    }
    if let Some(p) = free.iter().find(|p| !p.shapes_frequencies()) {
        return Err(UpdateError::NotFromFrequencies(p.name()));
    }
    if measured_hz.len() > 4 {
        return Err(UpdateError::TooManyFrequencies(measured_hz.len()));
    }
    if measured_hz.len() < free.len() {
        return Err(UpdateError::TooFewFrequencies {
            given: measured_hz.len(),
            free: free.len(),
        });
    }
    let start_model = check_start(start)?;
    let (bench, mode, cost, sig) = fit_frequencies(*start, free, measured_hz)
        .ok_or_else(|| UpdateError::NoFit("no pairing of the frequencies converged".into()))?;
    let model = bench
        .model()
        .ok_or_else(|| UpdateError::NoFit("the result is outside the ranges".into()))?;
    let (mut modes, crossed) = mode_report(&start_model, &model, bench.force_constant_n_per_a);
    for (j, &i) in mode.iter().enumerate() {
        modes[i].measured_frequency_hz = Some(measured_hz[j]);
    }
    let start_err: f64 = measured_hz
        .iter()
        .zip(&mode)
        .map(|(f, &i)| (start_model.modes()[i].frequency_hz() / f - 1.0).powi(2))
        .sum();
    let n = measured_hz.len() as f64;
    let warning = (measured_hz.len() == free.len()).then(|| {
        format!(
            "{} frequencies for {} parameters: no residual is left to estimate the uncertainty",
            measured_hz.len(),
            free.len()
        )
    });
    Ok(Update {
        source: "frequencies".into(),
        parameters: parameter_report(start, &bench, free, &sig),
        modes,
        rms_relative_error: (cost / n).sqrt(),
        start_rms_relative_error: (start_err / n).sqrt(),
        delay_s: None,
        delay_sigma_s: None,
        crossed_veering: crossed,
        cmp_cnmp: model.has_cnmp_zeros(),
        stiffness_over_beam: stiffness_over_beam(&bench),
        warning,
        flags: Vec::new(),
        bench: Some(bench),
    })
}

/// Whether a parameter is determined only by the closely spaced pair
/// (the Y modes' stiffness, the asymmetry, the operating point, and the
/// damping ratio at the pair).
pub(super) fn needs_the_pair(p: Parameter) -> bool {
    p.shapes_frequencies() || p == Parameter::ZetaCsm
}

/// Updates the free parameters of `start` to the measured FRF `data`
/// (steps 1–4 of the [module docs](super)). `fit` is the modal fit of the
/// same data (`modal_fit::fit`), for the start of step 2 and the pairing;
/// without it step 1 is skipped and `τ` starts at `T/2`.
///
/// **A pair the FRF does not show.** When neither mode of the updated
/// model that continues the start's closely spaced pair (its 3rd and 4th
/// modes, followed by their shapes) pairs with a fitted mode (MAC ≥
/// [`MIN_PAIR_MAC`]), e.g. near zero operating point where the Y modes
/// barely couple into x1, the parameters only the pair determines
/// (stiffness, asymmetry, operating point, `zeta_csm`) are not measured by
/// this FRF: they are held at their start values, the others refitted, and
/// the warning says so. (Without this, the fit uses the invisible pair to
/// fit noise and reports a wrong stiffness with a small 1σ.)
///
/// # Errors
/// [`UpdateError`]: nothing free, a start that is no bench, too few
/// coherent points, or no fit.
pub fn update_to_frf(
    start: &Bench,
    free: &[Parameter],
    data: &FrfData,
    path: &Path,
    fit: Option<&ModalFit>,
) -> Result<Update, UpdateError> {
    let u = update_frf_once(start, free, data, path, fit)?;
    // The pair is the start's 3rd and 4th modes (the secondary stages'),
    // followed through the update by their shapes (`start_mode`), not the
    // updated model's 3rd and 4th by frequency: an update that fits noise
    // can move the invisible pair below a mode the FRF shows, which would
    // then pass for the pair.
    let pair_seen = u
        .modes
        .iter()
        .filter(|m| m.start_mode >= 3)
        .any(|m| m.measured_frequency_hz.is_some());
    let held: Vec<Parameter> = free
        .iter()
        .copied()
        .filter(|p| needs_the_pair(*p))
        .collect();
    if fit.is_none() || pair_seen || held.is_empty() {
        return Ok(u);
    }
    let names: Vec<&str> = held.iter().map(|p| p.name()).collect();
    let why = format!(
        "the closely spaced pair is not seen in this FRF (no fitted mode pairs with either of its modes): {} not updated, held at the start values",
        names.join(", ")
    );
    let rest: Vec<Parameter> = free
        .iter()
        .copied()
        .filter(|p| !needs_the_pair(*p))
        .collect();
    if rest.is_empty() {
        return Err(UpdateError::NoFit(why));
    }
    let mut u = update_frf_once(start, &rest, data, path, fit)?;
    u.warning = Some(match u.warning {
        Some(w) => format!("{why}; {w}"),
        None => why,
    });
    Ok(u)
}

/// The benches an FRF update starts from: `start`, and with the mass
/// asymmetry free, `start` at the opposite asymmetry and ±0.05 from its own
/// (within [`ranges::MASS_ASYMMETRY`], none twice): the pair's order is
/// what an FRF decides least.
fn asymmetry_starts(start: &Bench, free: &[Parameter]) -> Vec<Bench> {
    let mut starts = vec![*start];
    if free.contains(&Parameter::MassAsymmetry) {
        let a0 = start.plant.mass_asymmetry;
        for a in [-a0, a0 - 0.05, a0 + 0.05] {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            if a > lo
                && a < hi
                && starts
                    .iter()
                    .all(|s| (s.plant.mass_asymmetry - a).abs() > 1e-3)
            {
                let mut s = *start;
                s.plant.mass_asymmetry = a;
                starts.push(s);
            }
        }
    }
    starts
}

/// An updated model's warning: an RMS error above [`MAX_UPDATE_ERROR`], or
/// a free parameter the FRF does not determine (1σ over half its value,
/// or none).
fn update_warning(rms: f64, parameters: &[super::UpdatedParameter]) -> Option<String> {
    if rms > MAX_UPDATE_ERROR {
        return Some(format!(
            "the updated model leaves an RMS error of {:.1} % over the coherent band (more than {:.0} %): the SR4DoF model does not explain this FRF",
            100.0 * rms,
            100.0 * MAX_UPDATE_ERROR
        ));
    }
    parameters
        .iter()
        .find(|p| p.free && p.sigma.is_none_or(|s| s > 0.5 * p.value.abs().max(1e-3)))
        .map(|p| {
            format!(
                "{} is not determined by this FRF (1σ {}): at an operating point near 0 the Y modes barely couple into x1",
                p.name,
                p.sigma.map_or("not estimable".into(), |s| format!("{s:.3e} {}", p.unit))
            )
        })
}

pub(super) fn update_frf_once(
    start: &Bench,
    free: &[Parameter],
    data: &FrfData,
    path: &Path,
    fit: Option<&ModalFit>,
) -> Result<Update, UpdateError> {
    if free.is_empty() {
        return Err(UpdateError::NoFreeParameter);
    }
    let start_model = check_start(start)?;
    let lines = modal_fit::independent_lines(data);
    let prep = Prepared::new(&lines, path);
    let coherent = prep.coherent.iter().filter(|c| **c).count();
    if coherent < modal_fit::MIN_POINTS {
        return Err(UpdateError::TooFewCoherentPoints(coherent));
    }
    let tau0 = fit.map_or(0.5 * path.period_s, |f| f.delay_s);

    // Step 1: frequency-shaping parameters to the fitted in-path modes,
    // from several asymmetries.
    let freq_free: Vec<Parameter> = free
        .iter()
        .copied()
        .filter(|p| p.shapes_frequencies())
        .collect();
    let measured = fit.map(measured_modes).unwrap_or_default();
    let starts = asymmetry_starts(start, free);
    let mut candidates: Vec<Bench> = Vec::new();
    for s in &starts {
        let b = if freq_free.is_empty() || measured.is_empty() {
            *s
        } else {
            fit_frequencies(*s, &freq_free, &measured).map_or(*s, |r| r.0)
        };
        candidates.push(b);
    }
    // Damping from the fitted modes paired by frequency, when free.
    let (zr, zc) = fit.map_or((None, None), |f| fitted_damping(f, &start_model));

    // Step 2: all free parameters and τ to the complex FRF, from the
    // three candidates of lowest cost.
    let target = Target::Frf(&prep);
    let mut scored: Vec<(f64, Bench)> = candidates
        .into_iter()
        .filter_map(|mut b| {
            if free.contains(&Parameter::ZetaRigid) {
                b.plant.damping.zeta_rigid = zr.unwrap_or(b.plant.damping.zeta_rigid);
            }
            if free.contains(&Parameter::ZetaCsm) {
                b.plant.damping.zeta_csm = zc.unwrap_or(b.plant.damping.zeta_csm);
            }
            let m = b.model().or_else(|| {
                b.plant.damping = start.plant.damping;
                b.model()
            })?;
            if free.contains(&Parameter::ForceConstant) {
                let kf = prep.best_force_constant(&m, tau0);
                if kf.is_finite() && kf > 0.0 {
                    b.force_constant_n_per_a = kf;
                }
            }
            let c = Problem::new(b, free, &target, tau0).cost_at(&DVector::from_vec(
                free.iter()
                    .map(|p| p.to_x(&b, p.value(&b)))
                    .chain([tau0 / path.period_s])
                    .collect(),
            ));
            c.is_finite().then_some((c, b))
        })
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best: Option<(DVector<f64>, f64, Bench)> = None;
    for (_, b) in scored.into_iter().take(3) {
        let (x, cost) = minimise(Problem::new(b, free, &target, tau0));
        if best.as_ref().is_none_or(|(_, c, _)| cost < *c) {
            best = Some((x, cost, b));
        }
    }
    let (x, cost, origin) =
        best.ok_or_else(|| UpdateError::NoFit("no start gave a bench in range".into()))?;
    let problem = Problem::new(origin, free, &target, tau0);
    let bench = problem.bench_at(&x);
    let tau = problem.tau_at(&x);
    let model = bench
        .model()
        .ok_or_else(|| UpdateError::NoFit("the result is outside the ranges".into()))?;
    let sig = coordinate_sigmas(&problem, &x, cost, prep.noise_estimated, &prep.dof);
    // The σ of a log or scaled coordinate of `origin` maps to the unit the
    // same way as for `start` (the transforms do not depend on the values).
    let parameters = parameter_report(start, &bench, free, &sig);
    let (mut modes, crossed) = mode_report(&start_model, &model, bench.force_constant_n_per_a);
    if let Some(f) = fit {
        pair_with_fit(&mut modes, f, &prep);
    }
    let rms = prep.rms_error(&bench, &model, tau);
    let mut flags: Vec<String> = Vec::new();
    if let Some(f) = fit.filter(|f| f.quality.checked && !f.quality.flags.is_empty()) {
        flags.push(format!(
            "the modal fit it starts from is flagged ({})",
            f.quality.flags.join("; ")
        ));
    }
    if prep.noise_estimated {
        // Against the cost's law under the noise alone, as the fit's
        // (`modal_fit::FitQuality`): χ²_ν for known variances, the scaled
        // χ² of a sum of 2F(2, d) for variances of d degrees of freedom.
        let nu = (problem.len() as f64 - x.len() as f64).max(1.0);
        let (mean, bound) = modal_fit::cost_reference(&prep.dof, x.len());
        let bound = bound / nu;
        if cost / nu > bound {
            flags.push(format!(
                "the updated model leaves more than the estimated noise: χ²/ν = {:.2} over {} lines (expected {:.2}, bound {bound:.2} at the {} level): the SR4DoF with these free parameters does not explain this FRF",
                cost / nu,
                prep.h.len(),
                mean / nu,
                modal_fit::RESIDUAL_TEST_LEVEL
            ));
        }
    }
    let mut start_kf = *start;
    start_kf.force_constant_n_per_a = bench.force_constant_n_per_a;
    let start_rms = prep.rms_error(&start_kf, &start_model, tau);
    let warning = update_warning(rms, &parameters);
    Ok(Update {
        source: "frf".into(),
        parameters,
        modes,
        rms_relative_error: rms,
        start_rms_relative_error: start_rms,
        delay_s: Some(tau),
        delay_sigma_s: sig[free.len()].map(|s| s * path.period_s),
        crossed_veering: crossed,
        cmp_cnmp: model.has_cnmp_zeros(),
        stiffness_over_beam: stiffness_over_beam(&bench),
        warning,
        flags,
        bench: Some(bench),
    })
}
