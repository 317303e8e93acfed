use super::*;

/// The multisine's bias bound by hand, and the realization a stall
/// leaves out: a 30 ms hold in realization 1's measured periods drops
/// it, the same in a transient period or one period's hold drops none.
#[test]
fn a_long_stall_leaves_its_realization_out() {
    // e = min(2π · 500 · 0.03, 2) · 0.5 A = 1 A;
    // (2 · 1 · 0.03 / (2 · 1e-3))² = 30² = 900.
    let b = held_multisine_bias(0.03, 500.0, 0.5, 1e-3, 2.0);
    assert!((b - 900.0).abs() < 1e-9, "{b}");
    // One 0.2 ms period at 500 Hz: (2 · 0.628 · 0.5 · 2e-4 / 2e-3)² = 3.9e-3.
    let e = 2.0 * std::f64::consts::PI * 500.0 * 2e-4;
    let by_hand = (2.0 * e * 0.5 * 2e-4 / (2.0 * 1e-3)).powi(2);
    assert!((held_multisine_bias(2e-4, 500.0, 0.5, 1e-3, 2.0) - by_hand).abs() < 1e-15);
    let plan = MultisinePlan {
        layout: Layout {
            lead_in_ticks: 100,
            period_ticks: 1000,
            transient_periods: 1,
            periods: 2,
            realizations: 3,
            lines: vec![1, 2, 3],
            tick_s: 1e-3,
        },
        phases: "random",
        crest_factor: 3.0,
        line_amplitude_a: [0.05, 0.1],
        band_hz: [1.0, 3.0],
        f_max_hz: 3.0,
        peak_a: 0.5,
    };
    // Realization 1 measures ticks 100 + 4000 … 100 + 6000.
    let (rep, keep) = StallReport::of_multisine(&[(4_600, 0.03)], &plan, 1e-3);
    assert_eq!(keep, vec![true, false, true]);
    assert_eq!(rep.excluded_realizations, 1);
    assert!(rep.line().contains("1 multisine realization(s) left out"));
    // In realization 1's transient period (3100 … 4100, the hold
    // 31 ticks before 4050): none.
    let (_, keep) = StallReport::of_multisine(&[(4_050, 0.03)], &plan, 1e-3);
    assert_eq!(keep, vec![true; 3]);
    // A one-tick overrun: its bias is far below 1e-4.
    let (rep, keep) = StallReport::of_multisine(&[(4_600, 1e-3)], &plan, 1e-3);
    assert_eq!((rep.count, keep), (1, vec![true; 3]));
}

/// The bias formula's figures: a one-period hold (0.2 ms) at 100 Hz in
/// a 20 s sweep of 0.1–500 Hz is 1.8e-8; 30 ms at 7.07 Hz in a 4 s
/// sweep is 1.6e-2 (a 12 % error of |H|), worked by hand from
/// `(2/3)(2π f h)² h² df/dt`.
#[test]
fn held_excitation_bias_by_hand() {
    let k20 = (5000f64).ln() / 20.0;
    let b = held_excitation_bias(100.0, 2e-4, 100.0 * k20);
    let by_hand =
        2.0 / 3.0 * (2.0 * std::f64::consts::PI * 100.0 * 2e-4f64).powi(2) * 4e-8 * 100.0 * k20;
    assert!((b / by_hand - 1.0).abs() < 1e-12 && b < 2e-8, "{b}");
    let f = 0.1 * 5000f64.sqrt();
    let b = held_excitation_bias(f, 0.03, f * (5000f64).ln() / 4.0);
    assert!((b - 1.605e-2).abs() < 0.001e-2, "{b}");
    // The error saturates at twice the amplitude: a hold of many periods.
    let long = held_excitation_bias(100.0, 1.0, 1.0);
    assert!((long - 2.0 / 3.0 * 4.0).abs() < 1e-12);
}
