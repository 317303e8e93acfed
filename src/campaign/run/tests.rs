use super::*;

#[test]
fn trim_masses_give_the_thesis_steps() {
    // Thesis 5.2.1: a 0.5 g mass is 0.8 % of the 60 g secondary stage.
    let one = trim_masses(0.06, 0.06, 0.0005, 0.008);
    assert_eq!((one.stage2, one.stage3), (1, 0));
    assert!((one.achieved_mass_asymmetry - 0.0005 / 0.06).abs() < 1e-15);
    // −2 %: masses on stage 3, m2/(m3 + n δ) − 1 nearest −0.02.
    let neg = trim_masses(0.06, 0.06, 0.0005, -0.02);
    assert_eq!((neg.stage2, neg.stage3), (0, 2));
    assert!((neg.achieved_mass_asymmetry - (0.06 / 0.061 - 1.0)).abs() < 1e-15);
    let zero = trim_masses(0.06, 0.06, 0.0005, 0.0);
    assert_eq!(
        (zero.stage2, zero.stage3, zero.achieved_mass_asymmetry),
        (0, 0, 0.0)
    );
    // Every target within half a mass of what it gets.
    for k in -80..=100 {
        let t = k as f64 * 1e-3;
        let m = trim_masses(0.06, 0.06, 0.0005, t);
        let per_mass = 0.0005 / 0.06;
        assert!(
            (m.achieved_mass_asymmetry - t).abs() <= 0.5 * per_mass * 1.1,
            "{t}: {m:?}"
        );
    }
}

#[test]
fn the_line_operator_reads_answers_and_stops_at_the_end_of_input() {
    let mut out = Vec::new();
    let mut op = LineOperator {
        input: io::Cursor::new("\nx\ns\nr\nq\n"),
        out: &mut out,
    };
    let answers: Vec<OperatorAnswer> = (0..5).map(|_| op.ask("cell").unwrap()).collect();
    assert_eq!(
        answers,
        [
            OperatorAnswer::Run,
            OperatorAnswer::Skip,
            OperatorAnswer::RedoPrevious,
            OperatorAnswer::Stop,
            OperatorAnswer::Stop
        ]
    );
    assert!(String::from_utf8(out)
        .unwrap()
        .contains("not an answer: \"x\""));
}
