use super::*;

/// A second-order system driven by white noise: the estimate matches the
/// analytic FRF (independent reference) and coherence tracks the SNR.
#[test]
fn h1_of_a_known_filter() {
    use rand::{Rng, SeedableRng};
    let fs = 1000.0;
    let n = 200_000;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    // y[n] = u[n] − 0.5 u[n−1]: H(e^{jω}) = 1 − 0.5 e^{−jω}.
    let y: Vec<f64> = (0..n)
        .map(|k| u[k] - if k > 0 { 0.5 * u[k - 1] } else { 0.0 })
        .collect();
    let cfg = IdentificationConfig {
        points_per_decade: 50,
        relative_resolution: 0.05,
        min_bins: 31,
        ..IdentificationConfig::default()
    };
    let s = Spectra::new(&u, &y, fs, &cfg);
    let frf = Frf::estimate(&s, 1.0, 400.0, &cfg);
    for (i, f) in frf.frequency_hz.iter().enumerate() {
        let w = 2.0 * PI * f / fs;
        let h = C64::new(1.0 - 0.5 * w.cos(), 0.5 * w.sin());
        assert!(
            (frf.magnitude_m_per_a[i] / h.norm() - 1.0).abs() < 0.02,
            "{f} Hz"
        );
        let dphi = frf.phase_deg[i] - h.arg().to_degrees();
        assert!(dphi.abs() < 1.0, "{f} Hz phase {dphi}");
        assert!(frf.coherence[i] > 0.999);
    }
    // With output noise of equal power, γ² ≈ |H|²/(|H|²+σ²/σu²).
    let ynoisy: Vec<f64> = y.iter().map(|v| v + rng.random_range(-1.0..1.0)).collect();
    let s = Spectra::new(&u, &ynoisy, fs, &cfg);
    // With random excitation the coherence-based σ is honest: the mean
    // of |Ĥ − H|²/σ² over the lines is 1 (lines overlap by about one
    // window, so ~130 lines give a spread of ~10 %).
    let frf = Frf::estimate(&s, 1.0, 400.0, &cfg);
    let mut ratio = 0.0;
    for (i, f) in frf.frequency_hz.iter().enumerate() {
        let w = 2.0 * PI * f / fs;
        let h = C64::new(1.0 - 0.5 * w.cos(), 0.5 * w.sin());
        ratio += (frf.response(i) - h).norm_sqr() / frf.sigma_m_per_a[i].powi(2);
        assert!((frf.resolution_hz[i] - 2.0 * s.half_width_hz(*f)).abs() < 1e-12);
    }
    let ratio = ratio / frf.frequency_hz.len() as f64;
    assert!((0.75..=1.25).contains(&ratio), "mean |ΔH|²/σ² = {ratio}");
    let e = s.estimate(250.0);
    let h2 = C64::new(1.0 - 0.5 * (PI / 2.0).cos(), 0.5 * (PI / 2.0).sin()).norm_sqr();
    let expected = h2 / (h2 + 1.0);
    assert!(
        (e.coherence - expected).abs() < 0.05,
        "{} vs {expected}",
        e.coherence
    );
}

/// An FRF of a few lines with σ and resolution.
fn small_frf() -> Frf {
    let mut frf = Frf::empty();
    for i in 0..12 {
        let f = 1.0 + i as f64;
        frf.push_checked([f, 1e-4 / f, -10.0 * f, 0.9, 1e-6 / f, 0.2, 14.0])
            .unwrap();
    }
    frf
}

#[test]
fn the_csv_round_trips_and_the_six_and_four_column_forms_still_read() {
    let frf = small_frf();
    let mut out = Vec::new();
    frf.write_csv_to(&mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    assert!(text.starts_with(
        "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof\n"
    ));
    let back = Frf::read_csv(&text).unwrap();
    for i in 0..12 {
        assert!((back.sigma_m_per_a[i] / frf.sigma_m_per_a[i] - 1.0).abs() < 1e-6);
        assert!((back.resolution_hz[i] - 0.2).abs() < 1e-9);
        assert_eq!(back.sigma_dof[i], 14.0);
    }
    let columns = |n: usize| -> String {
        text.lines()
            .map(|l| l.split(',').take(n).collect::<Vec<_>>().join(",") + "\n")
            .collect()
    };
    // The 6-column form: the degrees of freedom not stated (NaN).
    let six = Frf::read_csv(&columns(6)).unwrap();
    assert_eq!(six.sigma_m_per_a, back.sigma_m_per_a);
    assert!(six.sigma_dof.iter().all(|d| d.is_nan()));
    // The 4-column form: σ, resolution and degrees of freedom unknown.
    let four = columns(4);
    let old = Frf::read_csv(&four).unwrap();
    assert_eq!(old.frequency_hz, back.frequency_hz);
    assert!(old.sigma_m_per_a.iter().all(|s| s.is_nan()));
    assert!(old.resolution_hz.iter().all(|r| r.is_nan()));
    assert!(old.sigma_dof.iter().all(|d| d.is_nan()));
    // In the 7-column form σ, resolution and degrees of freedom must be
    // given; the degrees of freedom may be infinite (a known variance).
    for (from, to, col) in [
        (",1.000000e-6,", ",NaN,", "sigma_m_per_a"),
        (",1.000000e-6,", ",-1e-9,", "sigma_m_per_a"),
        (",2.000000e-1,", ",0,", "resolution_hz"),
        (",2.000000e-1,", ",inf,", "resolution_hz"),
        (",14\n", ",NaN\n", "sigma_dof"),
        (",14\n", ",-inf\n", "sigma_dof"),
        (",14\n", ",0.5\n", "sigma_dof"),
        (",14\n", ",-6\n", "sigma_dof"),
    ] {
        assert!(text.contains(from), "{from}");
        let e = Frf::read_csv(&text.replacen(from, to, 1)).unwrap_err();
        assert!(e.starts_with("line 2: ") && e.contains(col), "{to}: {e}");
    }
    let known = Frf::read_csv(&text.replacen(",14\n", ",inf\n", 1)).unwrap();
    assert_eq!(known.sigma_dof[0], f64::INFINITY);
    // Four fields under the 7-column header, seven under the 4-column one.
    let e = Frf::read_csv(&text.replacen(",1.000000e-6,2.000000e-1,14", "", 1)).unwrap_err();
    assert!(e.starts_with("line 2: 4 fields, expected 7"), "{e}");
    let mixed = four.replacen("1.000000,", "1.000000,1,1,1,", 2);
    assert!(Frf::read_csv(&mixed).is_err());
}

/// The 95 % circle of a response whose variance has `d` degrees of
/// freedom: `|Ĥ − H|²/σ̂² ~ F(2, d)`, against scipy's quantile
/// (`scipy.stats.f.ppf(0.95, 2, d)`: 5.1433 at d = 6, 3.7389 at d = 14,
/// 3.0411 at d = 200; `scipy.stats.expon.ppf(0.95)` = 2.9957 for a known
/// variance), and the 2.27σ̂ at M = 4 against 1.73σ̂ known.
#[test]
fn the_95_circle_follows_f_of_2_and_the_degrees_of_freedom() {
    for (d, q) in [
        (6.0, 5.143_252_849_784_718),
        (14.0, 3.738_891_832_440_735),
        (200.0, 3.041_055_791_125_247_6),
        (f64::INFINITY, 2.995_732_273_553_99),
        (f64::NAN, 2.995_732_273_553_99),
    ] {
        let r = radius_95(2.0, d);
        assert!((r / (2.0 * f64::sqrt(q)) - 1.0).abs() < 1e-9, "{d}: {r}");
    }
    assert!((radius_95(1.0, 6.0) - 2.27).abs() < 0.005);
    assert!((radius_95(1.0, f64::INFINITY) - 1.73).abs() < 0.005);
    assert!(radius_95(1.0, 0.0).is_infinite());
}

/// A recording written before σ and resolution existed: `read_frf`
/// gives them as unknown (NaN); one with them (a null: unknown too)
/// reads them back.
#[test]
fn recordings_with_and_without_sigma_read() {
    let write = |payload: serde_json::Value| -> Vec<u8> {
        let mut buf = std::io::Cursor::new(Vec::new());
        {
            let mut w = mcap::Writer::new(&mut buf).unwrap();
            let ch = w
                .add_channel(
                    0,
                    crate::record::TOPIC_FRF,
                    "json",
                    &std::collections::BTreeMap::new(),
                )
                .unwrap();
            w.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: ch,
                    sequence: 0,
                    log_time: 1,
                    publish_time: 1,
                },
                &serde_json::to_vec(&payload).unwrap(),
            )
            .unwrap();
            w.finish().unwrap();
        }
        buf.into_inner()
    };
    let frf = small_frf();
    let old = serde_json::json!({
        "frequency_hz": frf.frequency_hz,
        "magnitude_m_per_a": frf.magnitude_m_per_a,
        "phase_deg": frf.phase_deg,
        "coherence": frf.coherence,
    });
    let r = read_frf(&write(old.clone())).unwrap().frf;
    assert_eq!(r.frequency_hz, frf.frequency_hz);
    assert!(r.sigma_m_per_a.iter().all(|s| s.is_nan()));
    assert!(r.resolution_hz.iter().all(|s| s.is_nan()));
    // Degrees of freedom absent: not stated (NaN, taken as known).
    assert!(r.sigma_dof.iter().all(|d| d.is_nan()));
    let mut new = old.clone();
    let mut sigma: Vec<serde_json::Value> = frf.sigma_m_per_a.iter().map(|s| (*s).into()).collect();
    sigma[3] = serde_json::Value::Null;
    new["sigma_m_per_a"] = sigma.into();
    new["resolution_hz"] = frf.resolution_hz.clone().into();
    let mut dof: Vec<serde_json::Value> = vec![6.0.into(); 12];
    dof[5] = serde_json::Value::Null;
    new["sigma_dof"] = dof.into();
    let r = read_frf(&write(new.clone())).unwrap().frf;
    assert_eq!(r.sigma_m_per_a[0], frf.sigma_m_per_a[0]);
    assert!(r.sigma_m_per_a[3].is_nan());
    assert_eq!(r.resolution_hz, frf.resolution_hz);
    // A null is a known variance (what an infinite value is written as).
    assert_eq!(r.sigma_dof[0], 6.0);
    assert_eq!(r.sigma_dof[5], f64::INFINITY);
    let mut bad = new.clone();
    bad["sigma_dof"] = vec![0.5; 12].into();
    let e = read_frf(&write(bad)).unwrap_err();
    assert!(e.contains("point 1: sigma_dof"), "{e}");
    // Wrong lengths and values are refused naming the field.
    new["resolution_hz"] = vec![0.2; 3].into();
    let e = read_frf(&write(new.clone())).unwrap_err();
    assert!(e.contains("resolution_hz has 3 values"), "{e}");
    new["resolution_hz"] = vec![-0.2; 12].into();
    let e = read_frf(&write(new)).unwrap_err();
    assert!(e.contains("point 1: resolution_hz"), "{e}");
}

#[test]
fn unwrap_and_grid() {
    let mut p = vec![170.0, -170.0, -10.0, 175.0, -175.0];
    unwrap_deg(&mut p);
    // Each step takes the representative nearest the previous value.
    assert_eq!(p, vec![170.0, 190.0, 350.0, 175.0, 185.0]);
    let g = log_grid(1.0, 1000.0, 10);
    assert_eq!(g.len(), 31);
    assert!((g[10] - 10.0).abs() < 1e-9 && (g[30] - 1000.0).abs() < 1e-9);
    assert_eq!(fast_len(7), 8);
    assert_eq!(fast_len(121), 125);
}

/// At most `MAX_CSV_POINTS` lines: that many are read, one more is refused
/// at its line, before the rest of the file is looked at (lines 1, 2, …
/// mHz, each within the range of a line).
#[test]
fn an_frf_csv_of_more_than_max_points_is_refused_at_the_line_over() {
    use std::fmt::Write;
    let mut text = String::from("frequency_hz,magnitude_m_per_a,phase_deg,coherence\n");
    for i in 1..=MAX_CSV_POINTS {
        writeln!(text, "{i}e-3,1e-6,-1,1").unwrap();
    }
    assert_eq!(
        Frf::read_csv(&text).unwrap().frequency_hz.len(),
        MAX_CSV_POINTS
    );
    // One more line, then garbage that is never parsed.
    text.push_str("100001e-3,1e-6,-1,1\nnot,a,line\n");
    let e = Frf::read_csv(&text).unwrap_err();
    assert!(
        e.starts_with("line 100002: more than 100000 data lines"),
        "{e}"
    );
}

/// The 95 % confidence circle of H1 against scipy's F quantile
/// (`tests/data/h1_radius_reference.py`, which also checks by Monte Carlo
/// that the circle covers the true H in 95 % of estimates: 0.949–0.952
/// for 3 to 20 averages): `r² = 2/(2n − 2) · F(2, 2n − 2; 0.95) · (1 −
/// γ²)/γ² · |H|²`, for non-integer averages too.
#[test]
fn h1_radius_95_is_the_f_interval() {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/h1_radius_reference.json"),
    )
    .unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let h = C64::new(3.0, -4.0);
    for c in v["cases"].as_array().unwrap() {
        let n = c["averages"].as_f64().unwrap();
        let f95 = c["f95"].as_f64().unwrap();
        for g2 in [0.5, 0.9, 0.999] {
            let want = h.norm() * (2.0 / (2.0 * n - 2.0) * f95 * (1.0 - g2) / g2).sqrt();
            let got = h1_radius_95(h, g2, n);
            assert!(
                ((got - want) / want).abs() < 1e-9,
                "n {n} γ² {g2}: {got} vs {want}"
            );
        }
    }
    for c in v["coverage"].as_array().unwrap() {
        let p = c["coverage"].as_f64().unwrap();
        assert!((p - 0.95).abs() < 0.005, "{c}");
    }
    // Many averages: √3 times the complex 1σ (χ²₂'s 95 % point over 2);
    // no coherence or one average: no bound.
    let (g2, n) = (0.9, 1e6);
    let ratio = h1_radius_95(h, g2, n) / h1_sigma_m_per_a(h, g2, n);
    assert!((ratio - 2.9957f64.sqrt()).abs() < 1e-3, "{ratio}");
    assert!(h1_radius_95(h, 0.0, 5.0).is_infinite());
    assert!(h1_radius_95(h, 0.9, 1.0).is_infinite());
    assert!(h1_radius_95(C64::new(f64::NAN, 0.0), 0.9, 5.0).is_nan());
}
