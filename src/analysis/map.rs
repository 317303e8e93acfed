//! The CNMP map over operating point × mass asymmetry (thesis Fig 2-5,
//! 5-2) and the curve veering of the closely spaced pair (2.3, Fig 2-6,
//! Chapter 4).

use super::modal::{closely_spaced_pair, modal_terms, model_cnmp_damped, model_cnmp_undamped};
use bench_hal::param::ParamError;
use bench_plant::model::{Sr4dof, Sr4dofParams};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One cell of the map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct MapCell {
    /// Operating point Y1o, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23 = m2/m3 − 1, dimensionless.
    pub mass_asymmetry: f64,
    /// CMP-CNMP zeros in the undamped model (a complex root of N(u),
    /// Eq. 2-7; equivalently Δ < 0 of Eq. 2-8).
    pub cnmp: bool,
    /// CMP-CNMP zeros in the damped model (a complex zero in the right
    /// half plane; damping delays the transition, thesis 5.2.2).
    pub cnmp_damped: bool,
    /// The discriminant Δ of Eq. 2-8, m³/(N³·s⁶)·(rad/s)¹²: its sign is
    /// what the thesis maps.
    pub discriminant: f64,
}

/// The model of `base` at one operating point and asymmetry.
///
/// # Errors
/// [`ParamError`] naming `plant.operating_point_m` or
/// `plant.mass_asymmetry` if the cell is outside the model's range.
pub fn model_at(
    base: &Sr4dofParams,
    operating_point_m: f64,
    mass_asymmetry: f64,
) -> Result<Sr4dof, ParamError> {
    let mut p = *base;
    p.operating_point_m = operating_point_m;
    p.mass_asymmetry = mass_asymmetry;
    Sr4dof::new(p)
}

/// One cell of the map: the model of `base` at `operating_point_m` and
/// `mass_asymmetry` (eigen-decomposition, residues, damped and undamped
/// zeros and their types), reduced to the verdicts.
///
/// # Errors
/// [`ParamError`] as [`model_at`].
pub fn map_cell(
    base: &Sr4dofParams,
    operating_point_m: f64,
    mass_asymmetry: f64,
) -> Result<MapCell, ParamError> {
    let model = model_at(base, operating_point_m, mass_asymmetry)?;
    Ok(MapCell {
        operating_point_m,
        mass_asymmetry,
        cnmp: model_cnmp_undamped(&model),
        cnmp_damped: model_cnmp_damped(&model),
        discriminant: model.cnmp_discriminant(),
    })
}

/// The map on the grid `operating_points_m × mass_asymmetries`, row-major
/// with the asymmetry varying slowest. The cells are computed in parallel
/// on rayon's global pool (one thread per core); the result does not
/// depend on the number of threads.
///
/// # Errors
/// The [`ParamError`] of the first cell (in row-major order) outside the
/// model's range.
pub fn cnmp_map(
    base: &Sr4dofParams,
    operating_points_m: &[f64],
    mass_asymmetries: &[f64],
) -> Result<Vec<MapCell>, ParamError> {
    let n_op = operating_points_m.len();
    let cells: Vec<Result<MapCell, ParamError>> = (0..n_op * mass_asymmetries.len())
        .into_par_iter()
        .map(|i| {
            map_cell(
                base,
                operating_points_m[i % n_op],
                mass_asymmetries[i / n_op],
            )
        })
        .collect();
    cells.into_iter().collect()
}

/// One operating point of a veering curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct VeeringPoint {
    /// Operating point Y1o, m.
    pub operating_point_m: f64,
    /// Natural frequency of the lower mode of the pair, Hz.
    pub frequency_u_hz: f64,
    /// Natural frequency of the upper mode, Hz.
    pub frequency_v_hz: f64,
    /// Localisation of mode u, `(y2² − y3²)/(y2² + y3²)` of its shape:
    /// +1 on stage ② alone, −1 on stage ③ alone, 0 shared equally.
    pub localisation_u: f64,
    /// Localisation of mode v (same definition).
    pub localisation_v: f64,
    /// CMP-CNMP zeros (undamped).
    pub cnmp: bool,
    /// CMP-CNMP zeros (damped).
    pub cnmp_damped: bool,
}

/// The pair's frequencies against operating point for one asymmetry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct VeeringCurve {
    /// Mass asymmetry Δm23.
    pub mass_asymmetry: f64,
    /// The sweep, ascending in operating point.
    pub points: Vec<VeeringPoint>,
    /// Operating point of the closest approach of the pair (the veering
    /// point; mode crossing where the gap is 0), m, refined by golden
    /// section between the sweep's neighbours.
    pub closest_operating_point_m: f64,
    /// The gap `f_v − f_u` there, Hz.
    pub closest_gap_hz: f64,
    /// Mean frequency of the pair there, Hz.
    pub closest_frequency_hz: f64,
    /// Operating-point intervals `[from, to]` (m) of the sweep with
    /// CMP-CNMP zeros (undamped).
    pub cnmp_intervals_m: Vec<[f64; 2]>,
    /// The same for the damped model.
    pub cnmp_damped_intervals_m: Vec<[f64; 2]>,
}

fn localisation(shape: &[f64; 4]) -> f64 {
    let (y2, y3) = (shape[2] * shape[2], shape[3] * shape[3]);
    if y2 + y3 == 0.0 {
        0.0
    } else {
        (y2 - y3) / (y2 + y3)
    }
}

fn veering_point(base: &Sr4dofParams, op: f64, dm: f64) -> Result<VeeringPoint, ParamError> {
    let model = model_at(base, op, dm)?;
    let terms = modal_terms(&model);
    let (u, v) = closely_spaced_pair(&terms).expect("the SR4DoF has four modes");
    Ok(VeeringPoint {
        operating_point_m: op,
        frequency_u_hz: terms[u].frequency_hz,
        frequency_v_hz: terms[v].frequency_hz,
        localisation_u: localisation(&terms[u].shape),
        localisation_v: localisation(&terms[v].shape),
        cnmp: model_cnmp_undamped(&model),
        cnmp_damped: model_cnmp_damped(&model),
    })
}

fn intervals(points: &[VeeringPoint], pick: impl Fn(&VeeringPoint) -> bool) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = Vec::new();
    let mut open: Option<f64> = None;
    for (i, p) in points.iter().enumerate() {
        match (pick(p), open) {
            (true, None) => open = Some(p.operating_point_m),
            (false, Some(from)) => {
                out.push([from, points[i - 1].operating_point_m]);
                open = None;
            }
            _ => {}
        }
    }
    if let (Some(from), Some(last)) = (open, points.last()) {
        out.push([from, last.operating_point_m]);
    }
    out
}

/// The veering curve of the pair for asymmetry `mass_asymmetry` over
/// `operating_points_m` (ascending, at least 3).
///
/// # Errors
/// [`ParamError`] for a point outside the model's range.
pub fn veering_curve(
    base: &Sr4dofParams,
    mass_asymmetry: f64,
    operating_points_m: &[f64],
) -> Result<VeeringCurve, ParamError> {
    let points = operating_points_m
        .iter()
        .map(|&op| veering_point(base, op, mass_asymmetry))
        .collect::<Result<Vec<_>, _>>()?;
    let gap = |p: &VeeringPoint| p.frequency_v_hz - p.frequency_u_hz;
    let k = (0..points.len())
        .min_by(|&a, &b| gap(&points[a]).total_cmp(&gap(&points[b])))
        .expect("at least one point");
    // Golden-section refinement on [op[k−1], op[k+1]].
    let lo_i = k.saturating_sub(1);
    let hi_i = (k + 1).min(points.len() - 1);
    let (mut a, mut b) = (
        points[lo_i].operating_point_m,
        points[hi_i].operating_point_m,
    );
    let f = |op: f64| {
        veering_point(base, op, mass_asymmetry)
            .map(|p| gap(&p))
            .unwrap_or(f64::INFINITY)
    };
    let r = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        if b - a <= 1e-12 * b.abs().max(1e-9) {
            break;
        }
        let c = b - r * (b - a);
        let d = a + r * (b - a);
        if f(c) < f(d) {
            b = d;
        } else {
            a = c;
        }
    }
    let best = veering_point(base, 0.5 * (a + b), mass_asymmetry)?;
    let (best_op, best_pt) = if gap(&best) <= gap(&points[k]) {
        (0.5 * (a + b), best)
    } else {
        (points[k].operating_point_m, points[k])
    };
    Ok(VeeringCurve {
        mass_asymmetry,
        cnmp_intervals_m: intervals(&points, |p| p.cnmp),
        cnmp_damped_intervals_m: intervals(&points, |p| p.cnmp_damped),
        points,
        closest_operating_point_m: best_op,
        closest_gap_hz: gap(&best_pt),
        closest_frequency_hz: 0.5 * (best_pt.frequency_u_hz + best_pt.frequency_v_hz),
    })
}

/// `n` values from `lo` to `hi` inclusive, evenly spaced.
pub fn linspace(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![lo],
        _ => (0..n)
            .map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64)
            .collect(),
    }
}

/// Measured verdicts against the damped model's (thesis Fig 5-10): the
/// one comparison behind `bench map --measured` and a campaign's summary.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Agreement {
    /// Verdicts given (an undecided one is not compared).
    pub decided: usize,
    /// Decided verdicts equal to the damped model's.
    pub agree: usize,
    /// The decided verdicts that differ, as indices into the compared
    /// sequence, in its order.
    pub disagreements: Vec<usize>,
}

/// Compares each measured verdict (`Some(true)`: CMP-CNMP zeros measured,
/// `None`: undecided) with the damped model's verdict at the same point
/// ([`MapCell::cnmp_damped`]; damping delays the transition, thesis
/// 5.2.2, so a measurement is judged against the damped model).
pub fn agreement(compared: impl IntoIterator<Item = (Option<bool>, bool)>) -> Agreement {
    let mut a = Agreement::default();
    for (i, (measured, model_damped)) in compared.into_iter().enumerate() {
        let Some(m) = measured else { continue };
        a.decided += 1;
        if m == model_damped {
            a.agree += 1;
        } else {
            a.disagreements.push(i);
        }
    }
    a
}

/// The cell of `cells` nearest a point, distance measured in operating
/// point relative to the beam length `length_m` and in mass asymmetry
/// (both dimensionless); `None` for no cells.
pub fn nearest_cell(
    cells: &[MapCell],
    operating_point_m: f64,
    mass_asymmetry: f64,
    length_m: f64,
) -> Option<MapCell> {
    let d = |c: &MapCell| {
        ((c.operating_point_m - operating_point_m) / length_m).powi(2)
            + (c.mass_asymmetry - mass_asymmetry).powi(2)
    };
    cells.iter().min_by(|a, b| d(a).total_cmp(&d(b))).copied()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::BenchConfig;

    #[test]
    fn agreement_counts_decided_verdicts_only() {
        let a = agreement([
            (Some(true), true),
            (None, true),
            (Some(false), true),
            (Some(false), false),
            (Some(true), false),
        ]);
        assert_eq!(
            a,
            Agreement {
                decided: 4,
                agree: 2,
                disagreements: vec![2, 4]
            }
        );
    }

    fn base(file: &str) -> Sr4dofParams {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("bench-config")
            .join(file);
        BenchConfig::load(&path).unwrap().plant
    }

    #[test]
    fn parallel_map_cells_equal_the_full_analysis_of_each_bench() {
        // The map's lean verdicts (no zero lists, cells on rayon's pool)
        // against `analyze` of the same bench, cell by cell, on a grid
        // that crosses both CNMP boundaries and includes Y1o = 0 and
        // Δm23 = 0 (pole-zero cancellations), and on one thread.
        let p = base("sr4dof-ch5.toml");
        let l = p.beam.length_m;
        let ops = linspace(0.0, 0.10 * l, 41);
        let dms = linspace(-0.10, 0.10, 21);
        let cells = cnmp_map(&p, &ops, &dms).unwrap();
        assert_eq!(cells.len(), 41 * 21);
        let mut seen = (0, 0);
        for (i, c) in cells.iter().enumerate() {
            assert_eq!(c.operating_point_m, ops[i % 41]);
            assert_eq!(c.mass_asymmetry, dms[i / 41]);
            let a = crate::analysis::analyze(
                &model_at(&p, c.operating_point_m, c.mass_asymmetry).unwrap(),
            );
            assert_eq!((c.cnmp, c.cnmp_damped), (a.cnmp, a.cnmp_damped), "{c:?}");
            seen.0 += usize::from(c.cnmp);
            seen.1 += usize::from(c.cnmp_damped);
        }
        assert!(seen.0 > 0 && seen.1 > 0 && seen.0 < cells.len(), "{seen:?}");
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        assert_eq!(one.install(|| cnmp_map(&p, &ops, &dms).unwrap()), cells);
    }

    #[test]
    fn symmetric_stage_crosses_its_modes_near_6_6_percent_of_l() {
        // Thesis 2.3 / Fig 2-6a (Chapter 2 bench): with Δm23 = 0 the loci of
        // the 3rd and 4th modes intersect at Y1o = 6.6 % of L (mode
        // crossing), near 153 Hz (the shipped stiffness is calibrated to
        // Table 2-2's frequencies, see bench_plant::model).
        let p = base("sr4dof-ch2.toml");
        let l = p.beam.length_m;
        let c = veering_curve(&p, 0.0, &linspace(0.0, 0.12 * l, 121)).unwrap();
        let at = c.closest_operating_point_m / l;
        assert!(
            (0.060..=0.070).contains(&at),
            "crossing at {:.2} % of L",
            at * 100.0
        );
        assert!(c.closest_gap_hz < 0.05, "gap {} Hz", c.closest_gap_hz);
        assert!(
            c.closest_frequency_hz > 135.0 && c.closest_frequency_hz < 160.0,
            "{}",
            c.closest_frequency_hz
        );
    }

    #[test]
    fn asymmetry_turns_crossing_into_veering_with_localised_modes() {
        // Thesis 2.3: with Δm23 > 0 the loci approach and diverge (a gap at
        // the veering point), and at the veering point the modes localise
        // (mode localisation): one on stage ②, the other on ③, while at
        // Y1o = 0 both secondary stages move in each mode.
        let p = base("sr4dof-ch2.toml");
        let l = p.beam.length_m;
        let c = veering_curve(&p, 0.05, &linspace(0.0, 0.12 * l, 121)).unwrap();
        assert!(c.closest_gap_hz > 0.1, "gap {} Hz", c.closest_gap_hz);
        let at = veering_curve(&p, 0.05, &[c.closest_operating_point_m])
            .unwrap()
            .points[0];
        assert!(at.localisation_u * at.localisation_v < 0.0, "{at:?}");
        let start = c.points[0];
        assert!(
            at.localisation_u.abs() > start.localisation_u.abs()
                && at.localisation_v.abs() > start.localisation_v.abs(),
            "veering point {at:?}, Y1o = 0 {start:?}"
        );
    }

    #[test]
    fn map_is_free_of_cnmp_zeros_for_negative_asymmetry_and_has_them_for_positive() {
        // Thesis 2.2.3 (Fig 2-5, 5-10): "if m2 < m3, then the entire
        // operating range is free of CNMP zeros" (nor at Δm23 = 0, where the
        // pair's second mode is hidden); with m2 > m3 they arise in
        // specific ranges of Y1o.
        let p = base("sr4dof-ch2.toml");
        let l = p.beam.length_m;
        let ops = linspace(0.0, 0.1 * l, 41);
        let map = cnmp_map(
            &p,
            &ops,
            &[-0.15, -0.08, -0.04, -0.01, -0.001, 0.0, 0.01, 0.04, 0.08],
        )
        .unwrap();
        for c in &map {
            if c.mass_asymmetry <= 0.0 {
                assert!(!c.cnmp && !c.cnmp_damped, "{c:?}");
            }
            // Two derivations of the undamped verdict: typed roots of N(u)
            // and the sign of the discriminant of Eq. 2-8.
            assert_eq!(c.cnmp, c.discriminant < 0.0, "{c:?}");
        }
        for dm in [0.01, 0.04, 0.08] {
            assert!(
                map.iter().any(|c| c.mass_asymmetry == dm && c.cnmp),
                "none at Δm23 = {dm}"
            );
        }
    }

    #[test]
    fn dual_mmp_zeros_at_one_percent_and_3_3_percent_of_l() {
        // Thesis 4.4.2 / Fig 4-8: Chapter 2 bench, Δm23 = 1 %, Y1o = 3.3 %
        // of L: dual MMP zeros between the pair (which then become CMP-CNMP
        // towards the veering point).
        use crate::analysis::modal::undamped_zeros;
        use bench_plant::model::ZeroType;
        let p = base("sr4dof-ch2.toml");
        let model = model_at(&p, 0.033 * p.beam.length_m, 0.01).unwrap();
        let terms = modal_terms(&model);
        let (u, v) = closely_spaced_pair(&terms).unwrap();
        let (fu, fv) = (terms[u].frequency_hz, terms[v].frequency_hz);
        let between: Vec<_> = undamped_zeros(&model)
            .into_iter()
            .filter(|z| z.im_rad_s > 0.0 && z.frequency_hz > fu && z.frequency_hz < fv)
            .collect();
        assert_eq!(between.len(), 2, "pair {fu}–{fv} Hz: {between:?}");
        assert!(
            between.iter().all(|z| z.kind == ZeroType::Mmp),
            "{between:?}"
        );
    }
}
