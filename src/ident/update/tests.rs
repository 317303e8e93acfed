use super::*;

#[test]
fn order_preserving_pairings_are_the_combinations() {
    assert_eq!(order_preserving(4), vec![vec![0, 1, 2, 3]]);
    assert_eq!(order_preserving(3).len(), 4);
    assert_eq!(order_preserving(2).len(), 6);
    assert!(order_preserving(3).contains(&vec![0, 1, 3]));
}

#[test]
fn assignment_maximises_the_sum_and_skips_weak_pairs() {
    let mac = vec![vec![0.9, 0.8], vec![0.85, 0.1], vec![0.2, 0.3]];
    // 0→1, 1→0 (0.8 + 0.85) beats 0→0 alone (0.9); 2 pairs with none.
    assert_eq!(best_assignment(&mac), vec![Some(1), Some(0), None]);
}

#[test]
fn names_round_trip() {
    for p in Parameter::ALL {
        assert_eq!(Parameter::from_name(p.name()), Some(p));
        assert!(p.key().ends_with(p.name()));
    }
}
