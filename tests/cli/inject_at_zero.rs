//! A fault injected at 0 s latches like one injected later (issue 12, item
//! 15: `drop@0` and `jump@0` used to be invisible, because the first sample
//! already came after the gap or with the offset, and there was no sample
//! before it to compare with).

use crate::common;

use common::*;

#[test]
fn every_fault_injected_at_zero_seconds_latches_at_the_start() {
    for (kind, fault) in [
        ("nan", "probe_not_finite"),
        ("frozen", "stale_sample"),
        ("drop", "link"),
        ("jump", "position_jump"),
        ("out_of_range", "probe_out_of_range"),
    ] {
        let dir = tmp();
        let out = path_in(dir.path(), "run.mcap");
        let spec = format!("{kind}@0");
        let o = run(&[
            "control",
            "--fast",
            "--duration-s",
            "1",
            "--out",
            &out,
            "--inject-fault",
            &spec,
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(3), "{kind}@0: {err}");
        assert!(err.contains(fault), "{kind}@0: {err}");
        let msgs = mcap_messages(dir.path().join("run.mcap").as_path());
        let ev = msgs
            .iter()
            .find(|m| m.0 == "/bench/event" && m.2["kind"] == "fault")
            .unwrap_or_else(|| panic!("{kind}@0: no fault event"));
        assert_eq!(ev.2["fault"], fault, "{kind}@0");
        // Within the first K + 2 ticks (K = max_missed_samples = 3 for the
        // stale rule, which needs K + 1 repeats after the first sample).
        let tick = ev.2["tick"].as_u64().unwrap();
        assert!(tick <= 5, "{kind}@0: fault only at tick {tick}");
        // No current ever flowed after it.
        for m in msgs.iter().filter(|m| m.0 == "/bench/sample") {
            if m.2["tick"].as_u64().unwrap() >= tick {
                assert_eq!(m.2["current_command_a"].as_f64(), Some(0.0), "{kind}@0");
            }
        }
    }
}
