//! Mutations of the shipped `bench-config/sr4dof-ch5.toml`, key by key, for
//! every key that a protection depends on (`[safety]`, `[actuator]`,
//! `[emulator]`, the link timeouts and ratings of `[backend]`): NaN, ±inf,
//! negative, zero, denormal, huge, the integer extremes, the values just
//! outside and just inside each documented bound, wrong types and deletion,
//! plus property-based values (any bit pattern, and values clustered around
//! the bounds). For each: refused naming the key, or accepted with the value
//! inside its documented range, and then accepted by a run's setup too (the
//! simulator opened, the model built): `bench config check` refuses what the
//! runs refuse. For the damping pair, whose Rayleigh fit can give a mode
//! negative damping, generated pairs are accepted by the check exactly when
//! a run's setup accepts them.
//!
//! The ranges here are written from the documentation (README,
//! *Configuration reference*; the comments in the shipped files), not taken
//! from `config::limits`, so the test holds the code to what is documented.
//! At the shipped rate (5 kHz) and values.

use crate::common;

use bench::config::{BenchConfig, ConfigError};
use bench::rt::backend::{self, BackendSpec};
use bench_plant::model::Sr4dof;
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use toml::{Table, Value};

const SHIPPED: &str = "bench-config/sr4dof-ch5.toml";

fn shipped_text() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(SHIPPED))
        .expect("shipped config")
}

fn shipped_table() -> Table {
    shipped_text().parse().expect("shipped config is TOML")
}

/// What kind of value the key holds.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    /// `f64`
    Real,
    /// `u32`
    Count,
    /// `i32`
    Int,
    /// `usize` (a TOML integer, 0 … 2⁶³ − 1)
    Size,
}

/// A documented range: `lo`/`hi` with closed or open ends.
#[derive(Debug, Clone, Copy)]
struct Bounds {
    lo: f64,
    lo_closed: bool,
    hi: f64,
    hi_closed: bool,
}

impl Bounds {
    const fn new(lo: f64, lo_closed: bool, hi: f64, hi_closed: bool) -> Self {
        Self {
            lo,
            lo_closed,
            hi,
            hi_closed,
        }
    }

    fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && (if self.lo_closed {
                v >= self.lo
            } else {
                v > self.lo
            })
            && (if self.hi_closed {
                v <= self.hi
            } else {
                v < self.hi
            })
    }

    /// The values just outside each end (for a closed end the next float
    /// beyond it, for an open end the end itself), and just inside.
    fn edges(&self, kind: Kind) -> (Vec<f64>, Vec<f64>) {
        let (mut outside, mut inside) = (Vec::new(), Vec::new());
        if kind == Kind::Real {
            if self.lo_closed {
                outside.push(self.lo.next_down());
                inside.push(self.lo);
            } else {
                outside.push(self.lo);
                inside.push(self.lo.next_up());
            }
            if self.hi.is_finite() {
                if self.hi_closed {
                    outside.push(self.hi.next_up());
                    inside.push(self.hi);
                } else {
                    outside.push(self.hi);
                    inside.push(self.hi.next_down());
                }
            }
        } else {
            // Integer ends are closed.
            outside.extend([self.lo - 1.0, self.hi + 1.0]);
            inside.extend([self.lo, self.hi]);
        }
        (outside, inside)
    }
}

/// One key under test.
struct Spec {
    /// Dotted key, as the errors name it.
    key: &'static str,
    kind: Kind,
    /// Deleting it is a parse error (no default).
    required: bool,
    /// The documented range, at the shipped config's other values.
    range: Bounds,
}

/// Every key that a protection depends on, with its documented range for
/// the shipped Chapter 5 config (5 kHz loop, ±1 mm stop and probe,
/// `position_limit_m` 0.8 mm, 9.98 A peak, default serial timeout 25
/// periods = 5 ms, default CAN timeout 1 ms, K = 3).
fn specs() -> Vec<Spec> {
    let rate: f64 = 5000.0;
    let period = 1.0 / rate;
    // 0.1 s of ticks.
    let blind = (0.1 * rate).floor();
    // (K + 1) timeouts at most 1 s: serial 5 ms, CAN 1 ms.
    let k_max = blind.min(199.0).min(999.0);
    let s = |key, kind, required, range| Spec {
        key,
        kind,
        required,
        range,
    };
    use Kind::*;
    vec![
        s(
            "safety.position_limit_m",
            Real,
            true,
            Bounds::new(1e-6, true, 1e-3, false),
        ),
        s(
            "safety.max_overrun_s",
            Real,
            false,
            Bounds::new(0.0, false, 0.1, true),
        ),
        s(
            "safety.max_missed_samples",
            Count,
            false,
            Bounds::new(0.0, true, k_max, true),
        ),
        s(
            "safety.max_position_step_m",
            Real,
            false,
            // 1 m/s × one period (below the 0.8 mm limit).
            Bounds::new(1e-6, true, 1.0 * period, true),
        ),
        s(
            "safety.max_command_latency_s",
            Real,
            false,
            // (0, 0.1] s.
            Bounds::new(0.0, false, 0.1, true),
        ),
        s(
            "safety.i2t_peak_duration_s",
            Real,
            false,
            Bounds::new(0.01, true, 10.0, true),
        ),
        s(
            "safety.min_phase_margin_deg",
            Real,
            false,
            Bounds::new(20.0, true, 90.0, false),
        ),
        s(
            "safety.max_sensitivity_peak",
            Real,
            false,
            Bounds::new(1.0, false, 6.0, true),
        ),
        // At most the coil's rating (9.98 A shipped).
        s(
            "actuator.peak_current_a",
            Real,
            true,
            Bounds::new(0.0, false, 9.98, true),
        ),
        // At most the coil's rating (2.34 A) and the peak / 1.25 (7.984 A).
        s(
            "actuator.continuous_current_a",
            Real,
            true,
            Bounds::new(0.0, false, 2.34, true),
        ),
        // The coil's datasheet ratings: (0, 20] A, and the continuous one
        // below the peak one.
        s(
            "actuator.rated_peak_current_a",
            Real,
            false,
            Bounds::new(0.0, false, 20.0, true),
        ),
        s(
            "actuator.rated_continuous_current_a",
            Real,
            false,
            Bounds::new(0.0, false, 9.98, false),
        ),
        // Not protections themselves, but they set how hard and how fast
        // the coil pushes: [0.01, 1000] N/A, [10, 100 000] Hz.
        s(
            "actuator.force_constant_n_per_a",
            Real,
            true,
            Bounds::new(0.01, true, 1000.0, true),
        ),
        s(
            "actuator.bandwidth_hz",
            Real,
            true,
            Bounds::new(10.0, true, 100_000.0, true),
        ),
        s(
            "emulator.watchdog_ms",
            Real,
            false,
            // At least 1 ms and two periods (0.4 ms), at most 1 s.
            Bounds::new(1.0, true, 1000.0, true),
        ),
        s(
            "emulator.position_lsb_m",
            Real,
            false,
            Bounds::new(1e-3 / f64::from(i32::MAX), true, 1e-6, true),
        ),
        s(
            "emulator.priority",
            Int,
            false,
            Bounds::new(0.0, true, 99.0, true),
        ),
        s(
            "backend.serial.sample_timeout_periods",
            Real,
            false,
            // 1 … 1000 periods, at most 200 ms (1000 periods at 5 kHz).
            Bounds::new(1.0, true, 1000.0, true),
        ),
        s(
            "backend.serial.handshake_timeout_ms",
            Real,
            false,
            Bounds::new(1.0, true, 10_000.0, true),
        ),
        s(
            "backend.can.sample_timeout_ms",
            Real,
            false,
            Bounds::new(0.1, true, 200.0, true),
        ),
        s(
            "backend.can.peak_current_a",
            Real,
            false,
            Bounds::new(0.0, false, 20.0, true),
        ),
        s(
            "backend.can.continuous_current_a",
            Real,
            false,
            // At most the CAN device's default peak, 9.98 A.
            Bounds::new(0.0, false, 9.98, true),
        ),
        // The FRF's noise model: not a protection, but what the design's
        // margins are judged against. R in [0, 6]; n in [R + 2, 50] at the
        // shipped R = 2.
        s(
            "identification.lpm_degree",
            Size,
            false,
            Bounds::new(0.0, true, 6.0, true),
        ),
        s(
            "identification.lpm_half_width_bins",
            Size,
            false,
            Bounds::new(4.0, true, 50.0, true),
        ),
    ]
}

/// The table holding `key`'s last segment (created if missing), and that
/// segment.
fn slot<'a>(t: &'a mut Table, key: &'a str) -> (&'a mut Table, &'a str) {
    let mut parts: Vec<&str> = key.split('.').collect();
    let last = parts.pop().expect("dotted key");
    let mut t = t;
    for p in parts {
        t = t
            .entry(p)
            .or_insert_with(|| Value::Table(Table::new()))
            .as_table_mut()
            .expect("a table");
    }
    (t, last)
}

/// A mutation of one key.
#[derive(Debug, Clone)]
enum Mutation {
    /// A value of any TOML type.
    Set(Value),
    /// The key removed.
    Delete,
}

fn mutate(key: &str, m: &Mutation) -> String {
    let mut t = shipped_table();
    let (table, last) = slot(&mut t, key);
    match m {
        Mutation::Set(v) => {
            table.insert(last.to_string(), v.clone());
        }
        Mutation::Delete => {
            table.remove(last);
        }
    }
    toml::to_string(&t).expect("serialisable")
}

/// Loads and validates TOML text as `bench` does.
fn load(text: &str) -> Result<BenchConfig, ConfigError> {
    let p = Path::new("mutated.toml");
    let c = BenchConfig::from_toml(text, p)?;
    c.validate(p)?;
    Ok(c)
}

/// What a run does with a config before anything is enabled, past the
/// config's validation: the simulator opened and configured as `bench
/// chirp` and `bench control` open it (its model built and discretised),
/// and the model the loop check and the predictions build. `bench config
/// check` must refuse every config this refuses (one validation path).
fn run_setup(c: &BenchConfig) -> Result<(), String> {
    let p = Path::new("mutated.toml");
    Sr4dof::new(c.plant).map_err(|e| format!("the model: {e}"))?;
    backend::open(&BackendSpec::Sim, c, p, 1, None, f64::INFINITY)
        .map(drop)
        .map_err(|e| format!("the simulator: {e}"))
}

/// The value of `key` in a loaded config (`None` if unset).
fn value_of(c: &BenchConfig, key: &str) -> Option<f64> {
    let v: Value = toml::from_str(&c.to_toml()).expect("resolved config");
    let mut cur = &v;
    for p in key.split('.') {
        cur = cur.get(p)?;
    }
    match cur {
        Value::Float(f) => Some(*f),
        Value::Integer(i) => Some(*i as f64),
        other => panic!("{key} is {other:?}"),
    }
}

/// The numeric value a TOML value gives this key, if it is of a type the
/// key accepts (`None`: a type error is expected).
fn numeric(kind: Kind, v: &Value) -> Option<f64> {
    match (kind, v) {
        (Kind::Real, Value::Float(f)) => Some(*f),
        (Kind::Real, Value::Integer(i)) => Some(*i as f64),
        (Kind::Count, Value::Integer(i)) if u32::try_from(*i).is_ok() => Some(*i as f64),
        (Kind::Int, Value::Integer(i)) if i32::try_from(*i).is_ok() => Some(*i as f64),
        (Kind::Size, Value::Integer(i)) if usize::try_from(*i).is_ok() => Some(*i as f64),
        _ => None,
    }
}

/// The rule every mutation must obey; `Err` describes a violation. With
/// `setup`, a config accepted must pass a run's setup too ([`run_setup`]:
/// the simulator opened and discretised, about a millisecond).
fn judge(spec: &Spec, m: &Mutation, setup: bool) -> Result<(), String> {
    let text = mutate(spec.key, m);
    let last = spec.key.rsplit('.').next().expect("key");
    let got = load(&text);
    let expect = match m {
        Mutation::Delete if spec.required => None,
        Mutation::Delete => {
            // An optional key falls back to its default, inside its range
            // (or unset: the CAN timeout's computed default).
            return match got {
                Ok(c) => match value_of(&c, spec.key) {
                    Some(v) if !spec.range.contains(v) => {
                        Err(format!("deleted: default {v} outside {:?}", spec.range))
                    }
                    _ => Ok(()),
                },
                Err(e) => Err(format!("deleting an optional key refused: {e}")),
            };
        }
        Mutation::Set(v) => numeric(spec.kind, v).map(|x| (x, spec.range.contains(x))),
    };
    match (expect, got) {
        // Inside the documented range: accepted with exactly this value, or
        // refused for another key's cross-check (e.g. a peak current below
        // the continuous rating), never for this key.
        (Some((x, true)), Ok(c)) => match value_of(&c, spec.key) {
            Some(v) if v == x && setup => run_setup(&c)
                .map_err(|e| format!("{x:?} passes the config check, but a run refuses it: {e}")),
            Some(v) if v == x => Ok(()),
            other => Err(format!("accepted {x:?} but loaded {other:?}")),
        },
        (Some((x, true)), Err(ConfigError::Invalid { key, reason, .. })) => {
            if key == spec.key {
                Err(format!(
                    "{x:?} is inside the documented range but refused: {reason}"
                ))
            } else {
                Ok(())
            }
        }
        (Some((x, true)), Err(e)) => Err(format!("{x:?}: unexpected error {e}")),
        // Outside: refused naming this key.
        (Some((x, false)), Ok(_)) => Err(format!("{x:?} is outside {:?} but accepted", spec.range)),
        (Some((x, false)), Err(ConfigError::Invalid { key, reason, .. })) => {
            if key == spec.key {
                Ok(())
            } else {
                Err(format!(
                    "{x:?} refused naming {key} ({reason}), not {}",
                    spec.key
                ))
            }
        }
        (Some((x, false)), Err(e)) => Err(format!("{x:?}: unexpected error {e}")),
        // Wrong type, out of the integer type, or a required key deleted: a
        // parse error naming the key.
        (None, Ok(_)) => Err("accepted".into()),
        (None, Err(e @ ConfigError::Parse { .. })) => {
            let msg = e.to_string();
            if msg.contains(last) {
                Ok(())
            } else {
                Err(format!("parse error does not name {last}: {msg}"))
            }
        }
        (None, Err(e)) => Err(format!("unexpected error {e}")),
    }
}

/// The exhaustive table of mutations for one key.
fn table_for(spec: &Spec) -> Vec<Mutation> {
    let mut m = Vec::new();
    let set = Mutation::Set;
    match spec.kind {
        Kind::Real => {
            for x in [
                f64::NAN,
                -f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                -1.0,
                -5e-324,
                -0.0,
                0.0,
                5e-324,
                f64::MIN_POSITIVE,
                1e-300,
                1e300,
                f64::MAX,
                -1e300,
            ] {
                m.push(set(Value::Float(x)));
            }
            let (outside, inside) = spec.range.edges(spec.kind);
            for x in outside.into_iter().chain(inside) {
                m.push(set(Value::Float(x)));
            }
            // An integer where a real goes (TOML allows it for floats).
            m.push(set(Value::Integer(-1)));
            m.push(set(Value::Integer(0)));
            m.push(set(Value::Integer(i64::MAX)));
            m.push(set(Value::Integer(u32::MAX.into())));
        }
        Kind::Count | Kind::Int | Kind::Size => {
            for i in [
                i64::MIN,
                -1,
                0,
                1,
                i64::from(u32::MAX),
                i64::from(u32::MAX) + 1,
                i64::from(i32::MAX),
                i64::from(i32::MIN),
                i64::MAX,
            ] {
                m.push(set(Value::Integer(i)));
            }
            let (outside, inside) = spec.range.edges(spec.kind);
            for x in outside.into_iter().chain(inside) {
                m.push(set(Value::Integer(x as i64)));
            }
            // Reals where an integer goes.
            for x in [f64::NAN, f64::INFINITY, 3.0, 1e300, 5e-324] {
                m.push(set(Value::Float(x)));
            }
        }
    }
    // Wrong types.
    m.push(set(Value::String("1.0".into())));
    m.push(set(Value::String(String::new())));
    m.push(set(Value::Boolean(true)));
    m.push(set(Value::Array(vec![Value::Float(1.0)])));
    m.push(set(Value::Table(Table::new())));
    m.push(Mutation::Delete);
    m
}

#[test]
fn the_shipped_configs_and_the_test_fixtures_validate() {
    for name in ["sr4dof-ch5.toml", "sr4dof-ch2.toml"] {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("bench-config")
            .join(name);
        let c = BenchConfig::load(&p).unwrap();
        c.validate(&p).unwrap();
    }
    // The hardware and daemon tests' slow-VM link settings.
    let dir = common::tmp();
    let p = common::quiet_config(
        dir.path(),
        2.0,
        "\n[backend.serial]\nsample_timeout_periods = 200.0\n\n[emulator]\nwatchdog_ms = 300.0\n",
    );
    BenchConfig::load(&p).unwrap().validate(&p).unwrap();
    // Every spec holds for the shipped values themselves.
    let c = load(&shipped_text()).unwrap();
    for spec in specs() {
        if let Some(v) = value_of(&c, spec.key) {
            assert!(spec.range.contains(v), "{}: shipped {v}", spec.key);
        }
    }
}

#[test]
fn every_mutation_of_every_safety_key_is_refused_naming_it_or_stays_in_range() {
    let mut failures = Vec::new();
    let mut n = 0;
    for spec in specs() {
        for m in table_for(&spec) {
            n += 1;
            if let Err(why) = judge(&spec, &m, true) {
                failures.push(format!("{} = {m:?}: {why}", spec.key));
            }
        }
    }
    assert!(n > 500, "only {n} mutations");
    assert!(
        failures.is_empty(),
        "{} of {n} mutations broke the rule:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// The shipped config with `plant.damping` set to `zeta_rigid`,
/// `zeta_csm`.
fn with_damping(zeta_rigid: f64, zeta_csm: f64) -> String {
    let mut t = shipped_table();
    let (d, _) = slot(&mut t, "plant.damping.zeta_rigid");
    d.insert("zeta_rigid".into(), Value::Float(zeta_rigid));
    d.insert("zeta_csm".into(), Value::Float(zeta_csm));
    toml::to_string(&t).expect("serialisable")
}

/// `bench config check` and the runs judge a damping pair alike: accepted
/// by both, or refused by both, the check naming `plant.damping`.
fn judge_damping(zeta_rigid: f64, zeta_csm: f64) -> Result<(), String> {
    let p = Path::new("mutated.toml");
    let c = BenchConfig::from_toml(&with_damping(zeta_rigid, zeta_csm), p)
        .map_err(|e| format!("not parsed: {e}"))?;
    match (c.validate(p), run_setup(&c)) {
        (Ok(()), Ok(())) => Ok(()),
        (Err(ConfigError::Invalid { key, .. }), Err(_)) if key.starts_with("plant.damping.") => {
            Ok(())
        }
        (Err(e), Err(_)) => Err(format!("refused, but not naming plant.damping: {e}")),
        (Ok(()), Err(e)) => Err(format!("config check accepts it, a run refuses it: {e}")),
        (Err(e), Ok(())) => Err(format!("a run accepts it, config check refuses it: {e}")),
    }
}

/// Issue 46's six damping pairs, which `bench config check` accepted and
/// every run refused (the Rayleigh fit through them gives a mode negative
/// damping): refused by `bench config check` and by a run alike, exit 2
/// naming `plant.damping`; and the in-process rule holds for them and for
/// a grid of pairs over [0, 1)² that both sides of the line cross.
#[test]
fn config_check_refuses_the_damping_every_run_refuses() {
    const AUDIT: [(f64, f64); 6] = [
        (0.9, 0.001),
        (0.001, 0.9),
        (0.5, 0.0),
        (0.0, 0.5),
        (0.99, 0.0),
        (0.0, 0.99),
    ];
    let dir = common::tmp();
    for (i, (zr, zc)) in AUDIT.into_iter().enumerate() {
        let f = common::path_in(dir.path(), &format!("damping{i}.toml"));
        std::fs::write(&f, with_damping(zr, zc)).unwrap();
        let o = common::run(&["config", "check", &f]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(
            o.status.code(),
            Some(2),
            "({zr}, {zc}): config check: {err}"
        );
        assert!(err.contains("plant.damping.zeta_rigid"), "{err}");
        let out = common::path_in(dir.path(), &format!("run{i}.mcap"));
        let o = common::run(&[
            "chirp",
            "--config",
            &f,
            "--duration-s",
            "0.2",
            "--out",
            &out,
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "({zr}, {zc}): chirp: {err}");
        judge_damping(zr, zc).unwrap();
    }
    let (mut accepted, mut refused) = (0, 0);
    for i in 0..20 {
        for j in 0..20 {
            let (zr, zc) = (f64::from(i) * 0.05, f64::from(j) * 0.05);
            if let Err(why) = judge_damping(zr, zc) {
                panic!("({zr}, {zc}): {why}");
            }
            let c = BenchConfig::from_toml(&with_damping(zr, zc), Path::new("x.toml")).unwrap();
            if run_setup(&c).is_ok() {
                accepted += 1;
            } else {
                refused += 1;
            }
        }
    }
    assert!(
        accepted > 20 && refused > 20,
        "{accepted} accepted, {refused} refused"
    );
}

/// A real value for key `spec`: any bit pattern, or near one of the bounds
/// (a few ulps, or a relative nudge), or anywhere inside.
fn real_near(spec: &Spec, bits: u64, mode: u8, ulps: i32, frac: f64) -> f64 {
    let r = spec.range;
    let hi = if r.hi.is_finite() { r.hi } else { 1e6 };
    let nudge = |mut x: f64| {
        for _ in 0..ulps.unsigned_abs() {
            x = if ulps > 0 { x.next_up() } else { x.next_down() };
        }
        x
    };
    match mode % 5 {
        0 => f64::from_bits(bits),
        1 => nudge(r.lo),
        2 => nudge(hi),
        3 => r.lo + frac * (hi - r.lo),
        _ => hi * (1.0 + (frac - 0.5) * 1e-6 * f64::from(ulps)),
    }
}

/// A damping ratio: any bit pattern, anywhere in or around [0, 1), or
/// near either end of it.
fn damping_ratio() -> impl Strategy<Value = f64> {
    prop_oneof![
        any::<u64>().prop_map(f64::from_bits),
        -0.1f64..1.1,
        0.0f64..0.05,
        (0u32..8).prop_map(|n| (0..n).fold(1.0f64, |x, _| x.next_down())),
        (0u32..8).prop_map(|n| (0..n).fold(0.0f64, |x, _| x.next_up())),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 500, ..ProptestConfig::default() })]

    /// Property: for any pair of damping ratios (any bit pattern, or
    /// anywhere in and around [0, 1)), `bench config check` accepts the
    /// config exactly when a run's setup does.
    #[test]
    fn config_check_accepts_a_damping_pair_exactly_when_the_runs_do(
        zr in damping_ratio(),
        zc in damping_ratio(),
    ) {
        if let Err(why) = judge_damping(zr, zc) {
            prop_assert!(false, "({:?}, {:?}): {}", zr, zc, why);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, ..ProptestConfig::default() })]

    /// Property: for any value of any safety key, `bench` refuses it naming
    /// the key exactly when it is outside the documented range.
    #[test]
    fn any_value_of_any_safety_key_obeys_its_documented_range(
        which in 0usize..64,
        bits in any::<u64>(),
        mode in any::<u8>(),
        ulps in -4i32..=4,
        frac in 0.0f64..=1.0,
        wide in any::<i64>(),
    ) {
        let specs = specs();
        let spec = &specs[which % specs.len()];
        let value = match spec.kind {
            Kind::Real => Value::Float(real_near(spec, bits, mode, ulps, frac)),
            Kind::Count | Kind::Int | Kind::Size => Value::Integer(match mode % 4 {
                0 => wide,
                1 => spec.range.lo as i64 + i64::from(ulps),
                2 => spec.range.hi as i64 + i64::from(ulps),
                _ => (spec.range.lo + frac * (spec.range.hi - spec.range.lo)).round() as i64,
            }),
        };
        let m = Mutation::Set(value);
        if let Err(why) = judge(spec, &m, false) {
            prop_assert!(false, "{} = {:?}: {}", spec.key, m, why);
        }
    }

    /// K's bounds follow the loop rate: at any rate, K is refused naming
    /// the key exactly when above 0.1 s of ticks or when K + 1 sample
    /// timeouts exceed 1 s. (The overrun bound is a time,
    /// `safety.max_overrun_s`, whatever the rate.)
    #[test]
    fn the_count_bounds_follow_the_loop_rate(
        rate in 100.0f64..=100_000.0,
        n in 0u32..=20_000,
    ) {
        let mut t = shipped_table();
        t["loop"].as_table_mut().unwrap().insert("rate_hz".into(), Value::Float(rate));
        // A jump limit that fits every rate (1 m/s × 10 µs), and a serial
        // timeout within 200 ms at every rate.
        t["safety"].as_table_mut().unwrap()
            .insert("max_position_step_m".into(), Value::Float(5e-6));
        let mut serial = Table::new();
        serial.insert("sample_timeout_periods".into(), Value::Float(10.0));
        let mut backend = Table::new();
        backend.insert("serial".into(), Value::Table(serial));
        t.insert("backend".into(), Value::Table(backend));
        let key = "max_missed_samples";
        t["safety"].as_table_mut().unwrap().insert(key.into(), Value::Integer(n.into()));
        let text = toml::to_string(&t).unwrap();
        let blind = (0.1 * rate).floor();
        // The serial timeout (10 periods) or the CAN default (2 periods,
        // at least 1 ms), whichever is longer.
        let timeout_s = (10.0 / rate).max(1e-3);
        let ok = f64::from(n) <= blind && (f64::from(n) + 1.0) * timeout_s <= 1.0 + 1e-9;
        let dotted = format!("safety.{key}");
        match load(&text) {
            Err(ConfigError::Invalid { key: k, reason, .. }) if k == dotted => {
                prop_assert!(!ok, "{dotted} = {n} at {rate} Hz refused: {reason}");
            }
            Err(ConfigError::Invalid { key: k, .. }) => {
                // Another key (the chirp's band at a low rate): fine, if
                // this value was inside its range.
                prop_assert!(ok, "{dotted} = {n} at {rate} Hz: refused naming {k} instead");
            }
            Err(e) => prop_assert!(false, "{e}"),
            Ok(_) => prop_assert!(ok, "{dotted} = {n} at {rate} Hz accepted"),
        }
    }
}

/// The same rule through the command line: `bench control --fast
/// --check-only` exits 2 naming the key, for each key's non-finite, just
/// out-of-range, wrong-type and (where required) deleted values.
#[test]
fn the_cli_refuses_every_out_of_range_safety_key_with_exit_2() {
    let dir = common::tmp();
    let mut n = 0;
    let mut failures = Vec::new();
    for spec in specs() {
        let (outside, _) = spec.range.edges(spec.kind);
        let mut ms: Vec<Mutation> = outside
            .into_iter()
            .map(|x| match spec.kind {
                Kind::Real => Mutation::Set(Value::Float(x)),
                _ => Mutation::Set(Value::Integer(x as i64)),
            })
            .collect();
        ms.push(Mutation::Set(match spec.kind {
            Kind::Real => Value::Float(f64::NAN),
            _ => Value::Integer(i64::from(u32::MAX)),
        }));
        ms.push(Mutation::Set(Value::String("1".into())));
        if spec.required {
            ms.push(Mutation::Delete);
        }
        for m in ms {
            // The documented range's open upper end at infinity has no value
            // just outside it.
            if matches!(&m, Mutation::Set(Value::Float(x)) if x.is_infinite()) {
                continue;
            }
            n += 1;
            let path: PathBuf = dir.path().join(format!("m{n}.toml"));
            std::fs::write(&path, mutate(spec.key, &m)).unwrap();
            let o = common::run(&[
                "control",
                "--fast",
                "--check-only",
                "--config",
                &path.display().to_string(),
            ]);
            let err = String::from_utf8_lossy(&o.stderr);
            let last = spec.key.rsplit('.').next().unwrap();
            if o.status.code() != Some(2) || !err.contains(last) {
                failures.push(format!(
                    "{} = {m:?}: exit {:?}, stderr {err}",
                    spec.key,
                    o.status.code()
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {n} command lines:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// Unit slips in the file (issue 17, item 5): `mass_asymmetry = 10`
/// (meant as 10 %) and `operating_point_m = 3` (meant as 3 mm) are refused
/// with exit 2 naming the file and the key, with the value in the intended
/// unit; a TOML syntax or type error keeps the parser's multi-line display
/// (the offending line and a caret under it) and names the file.
#[test]
fn unit_slips_in_the_file_get_a_hint_and_toml_errors_keep_their_caret() {
    let dir = common::tmp();
    let text = shipped_text();
    for (from, to, want) in [
        (
            "mass_asymmetry = 0.10 ",
            "mass_asymmetry = 10   ",
            vec!["plant.mass_asymmetry", "0.10 = 10 %", "give 0.1"],
        ),
        (
            "operating_point_m = 3.8e-3",
            "operating_point_m = 3.8   ",
            vec!["plant.operating_point_m", "3.8 mm = 0.0038 m"],
        ),
    ] {
        assert!(text.contains(from), "the shipped file has {from:?}");
        let path = dir.path().join("slip.toml");
        std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
        let p = path.display().to_string();
        let o = common::run(&["chirp", "--config", &p, "--duration-s", "0.1"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(&p), "names the file: {err}");
        for w in want {
            assert!(err.contains(w), "no {w:?} in {err}");
        }
    }
    // A type error: multi-line, the line and the caret, not joined by " | ".
    let path = dir.path().join("typo.toml");
    std::fs::write(
        &path,
        text.replacen("rate_hz = 5000.0 ", "rate_hz = \"5 kHz\"", 1),
    )
    .unwrap();
    let p = path.display().to_string();
    let o = common::run(&["control", "--fast", "--check-only", "--config", &p]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(&p), "{err}");
    assert!(err.lines().count() >= 4, "multi-line: {err}");
    let lines: Vec<&str> = err.lines().collect();
    let at = lines
        .iter()
        .position(|l| l.contains("rate_hz = \"5 kHz\""))
        .unwrap_or_else(|| panic!("the offending line is shown: {err}"));
    let caret = lines[at + 1];
    let col = caret.find('^').expect("a caret line under it");
    assert_eq!(&lines[at][col..col + 7], "\"5 kHz\"", "{err}");
    // Not joined into one line: the gutter line, the source line and the
    // caret line stay lines of their own.
    let gutter = lines[at].split(" |").next().unwrap_or_default().trim();
    assert!(gutter.parse::<usize>().is_ok(), "not joined: {err}");
}

/// One step into an array's element: an index, or an inline table's field.
#[derive(Debug, Clone)]
enum Step {
    Index(usize),
    Field(String),
}

/// `[1][1]`, `[0].zeta`: the steps as a key path suffix.
fn render(steps: &[Step]) -> String {
    steps
        .iter()
        .map(|s| match s {
            Step::Index(i) => format!("[{i}]"),
            Step::Field(f) => format!(".{f}"),
        })
        .collect()
}

/// The dotted keys of every array-valued key under `t` (through tables
/// and inline tables).
fn array_keys(t: &toml_edit::Table, path: &str, out: &mut Vec<String>) {
    fn in_value(v: &toml_edit::Value, path: String, out: &mut Vec<String>) {
        match v {
            toml_edit::Value::Array(_) => out.push(path),
            toml_edit::Value::InlineTable(t) => {
                for (k, v) in t.iter() {
                    in_value(v, format!("{path}.{k}"), out);
                }
            }
            _ => {}
        }
    }
    for (k, item) in t.iter() {
        let p = if path.is_empty() {
            k.to_string()
        } else {
            format!("{path}.{k}")
        };
        match item {
            toml_edit::Item::Table(t) => array_keys(t, &p, out),
            toml_edit::Item::Value(v) => in_value(v, p, out),
            _ => {}
        }
    }
}

/// Every node inside an array, at every depth: its elements, the elements
/// of inner arrays, the fields of inline tables.
fn nodes(v: &toml_edit::Value, at: Vec<Step>, out: &mut Vec<Vec<Step>>) {
    if !at.is_empty() {
        out.push(at.clone());
    }
    match v {
        toml_edit::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                let mut s = at.clone();
                s.push(Step::Index(i));
                nodes(x, s, out);
            }
        }
        toml_edit::Value::InlineTable(t) => {
            for (k, x) in t.iter() {
                let mut s = at.clone();
                s.push(Step::Field(k.to_string()));
                nodes(x, s, out);
            }
        }
        _ => {}
    }
}

fn node_mut<'a>(v: &'a mut toml_edit::Value, steps: &[Step]) -> &'a mut toml_edit::Value {
    steps.iter().fold(v, |v, s| match (s, v) {
        (Step::Index(i), toml_edit::Value::Array(a)) => a.get_mut(*i).expect("element"),
        (Step::Field(f), toml_edit::Value::InlineTable(t)) => t.get_mut(f).expect("field"),
        (s, v) => panic!("{s:?} into {v:?}"),
    })
}

fn key_mut<'a>(doc: &'a mut toml_edit::DocumentMut, key: &str) -> &'a mut toml_edit::Value {
    let mut item = doc.as_item_mut();
    for k in key.split('.') {
        item = &mut item[k];
    }
    item.as_value_mut().expect("a value")
}

/// Issue 25: for every array-valued key of the shipped configs, every
/// element at every depth (an element, an element of an inner array, a
/// field of an inline table) set in turn to a value of the wrong type
/// (a string for a number, a number for anything else), with the array
/// written one element per line, where the parser's line and caret do not
/// show the key: the refusal names the element's full path
/// (`chirp.amplitude_profile[1][1]`, `controller.fast.complex_zeros[1].zeta`),
/// in the library and at the command line (exit 2).
#[test]
fn a_wrong_type_in_a_multi_line_array_names_the_element() {
    let dir = common::tmp();
    let mut checked = Vec::new();
    for file in [
        "bench-config/sr4dof-ch5.toml",
        "bench-config/sr4dof-ch2.toml",
    ] {
        let text =
            std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(file)).unwrap();
        let doc: toml_edit::DocumentMut = text.parse().unwrap();
        let mut keys = Vec::new();
        array_keys(doc.as_table(), "", &mut keys);
        for key in keys {
            let mut all = Vec::new();
            nodes(
                &key_mut(&mut doc.clone(), &key).clone(),
                Vec::new(),
                &mut all,
            );
            assert!(!all.is_empty(), "{file}: {key} is empty");
            for steps in all {
                let mut d = doc.clone();
                let array = key_mut(&mut d, &key);
                if let toml_edit::Value::Array(a) = array {
                    for v in a.iter_mut() {
                        v.decor_mut().set_prefix("\n    ");
                    }
                    a.set_trailing("\n");
                    a.set_trailing_comma(true);
                }
                let node = node_mut(array, &steps);
                let decor = node.decor().clone();
                *node = match node {
                    toml_edit::Value::Float(_) | toml_edit::Value::Integer(_) => "wrong".into(),
                    _ => 1.5.into(),
                };
                *node.decor_mut() = decor;
                let path = format!("{key}{}", render(&steps));
                let mutated = d.to_string();
                let e = BenchConfig::from_toml(&mutated, Path::new("m.toml"))
                    .expect_err(&format!("{path} of a wrong type accepted:\n{mutated}"));
                let msg = e.to_string();
                assert!(
                    matches!(e, ConfigError::Parse { .. })
                        && msg.starts_with(&format!("config m.toml: {path}: ")),
                    "{file}: does not start with {path}: {msg}"
                );
                checked.push((file, path, mutated));
            }
        }
    }
    // All the keys the shipped configs have as arrays, elements included.
    for want in [
        "chirp.amplitude_profile[1][1]",
        "plant.disturbance.band_hz[1]",
        "controller.fast.real_poles_rad_s[1]",
        "controller.fast.complex_zeros[1].zeta",
    ] {
        assert!(checked.iter().any(|c| c.1 == want), "{want} not checked");
    }
    // At the command line: exit 2, the path on stderr.
    for (_, path, mutated) in checked.iter().step_by(7) {
        let p = dir.path().join("m.toml");
        std::fs::write(&p, mutated).unwrap();
        let o = common::run(&["config", "check", p.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(&format!("{path}: ")), "{path}: {err}");
    }
}

/// Refusals that compare two keys name the key refused first and the key
/// it is compared with in the message.
#[test]
fn a_refusal_between_two_keys_names_both() {
    let text = shipped_text();
    for (from, to, refused, other) in [
        (
            "f_start_hz = 0.1 ",
            "f_start_hz = 600.0 ",
            "chirp.f_start_hz",
            "chirp.f_end_hz",
        ),
        (
            "f_end_hz = 500.0",
            "f_end_hz = 2600.0",
            "chirp.f_end_hz",
            "loop.rate_hz",
        ),
        (
            "amplitude_a = 0.5 ",
            "amplitude_a = 15.0 ",
            "chirp.amplitude_a",
            "actuator.peak_current_a",
        ),
        (
            "taper_s = 0.5 ",
            "taper_s = 40.0 ",
            "chirp.taper_s",
            "chirp.duration_s",
        ),
        (
            "mechanical_stop_m = 1.0e-3",
            "mechanical_stop_m = 0.5e-3",
            "safety.position_limit_m",
            "stage.mechanical_stop_m",
        ),
        (
            "range_m = 1.0e-3 ",
            "range_m = 0.5e-3 ",
            "safety.position_limit_m",
            "probe.range_m",
        ),
        (
            "step_m = 10.0e-6",
            "step_m = 0.9e-3",
            "step.step_m",
            "safety.position_limit_m",
        ),
        (
            "duration_s = 4.0 ",
            "duration_s = 0.1 ",
            "step.duration_s",
            "step.settle_s",
        ),
        (
            "continuous_current_a = 2.34",
            "continuous_current_a = 12.0",
            "actuator.continuous_current_a",
            "actuator.rated_continuous_current_a",
        ),
        // A peak too close to the continuous rating leaves no I²t budget:
        // the continuous rating is refused, naming the peak.
        (
            "peak_current_a = 9.98",
            "peak_current_a = 2.5",
            "actuator.continuous_current_a",
            "actuator.peak_current_a",
        ),
        (
            "band_hz = [1.0, 20.0]",
            "band_hz = [30.0, 20.0]",
            "plant.disturbance.band_hz[0]",
            "plant.disturbance.band_hz[1]",
        ),
        (
            "[[12.0, 1.0], [20.0, 0.1]",
            "[[22.0, 1.0], [20.0, 0.1]",
            "chirp.amplitude_profile[1][0]",
            "chirp.amplitude_profile[0][0]",
        ),
        (
            "points_per_decade = 400 ",
            "points_per_decade = 10000 ",
            "identification.points_per_decade",
            "identification.relative_resolution",
        ),
        (
            "relative_resolution = 0.004",
            "relative_resolution = 0.1  ",
            "identification.points_per_decade",
            "identification.relative_resolution",
        ),
        (
            "lpm_degree = 2 ",
            "lpm_degree = 5 ",
            "identification.lpm_half_width_bins",
            "identification.lpm_degree",
        ),
    ] {
        assert!(text.contains(from), "the shipped file has {from:?}");
        let e = load(&text.replacen(from, to, 1)).expect_err(to);
        let msg = e.to_string();
        assert!(
            msg.starts_with(&format!("config mutated.toml: {refused}: ")),
            "{to}: {msg}"
        );
        let reason = msg.split_once(&format!("{refused}: ")).unwrap().1;
        assert!(reason.contains(other), "{to}: {msg}");
    }
}

/// `[chirp] kind`, the excitation's spelling before `[excitation]`, is
/// read as `excitation.kind` (issue 43) for every kind: the config is the
/// one the new spelling gives, and `bench config check` accepts it with a
/// deprecation warning naming the file and the new spelling. Both
/// spellings at once are refused naming `chirp.kind`; a bad old value is
/// refused naming the kind.
#[test]
fn the_old_spelling_of_the_excitation_kind_is_read_with_a_warning() {
    let new = shipped_text();
    let block_start = new
        .find("[excitation]\n")
        .expect("[excitation] in the shipped file");
    let block_end = block_start + new[block_start..].find("\n[chirp]\n").unwrap() + 1;
    let dir = common::tmp();
    for kind in ["exponential", "linear", "multisine"] {
        // The new spelling with this kind (a multisine without the
        // sweep's keys), and the old: the kind under [chirp].
        let mut with_new = new.replacen("kind = \"exponential\"", &format!("kind = \"{kind}\""), 1);
        if kind == "multisine" {
            with_new = with_new
                .lines()
                .filter(|l| !l.starts_with("duration_s = ") && !l.starts_with("taper_s = "))
                .map(|l| format!("{l}\n"))
                .collect();
        }
        let start = with_new.find("[excitation]\n").unwrap();
        let end = start + with_new[start..].find("\n[chirp]\n").unwrap() + 1;
        let old = format!(
            "{}[chirp]\nkind = \"{kind}\"\n{}",
            &with_new[..start],
            &with_new[end + "[chirp]\n".len()..]
        );
        assert!(
            !old.contains("[excitation]"),
            "{kind}: the old text has no [excitation]"
        );
        let p = Path::new("x.toml");
        let (a, b) = (
            BenchConfig::from_toml(&with_new, p).unwrap(),
            BenchConfig::from_toml(&old, p).unwrap(),
        );
        assert_eq!(a, b, "{kind}: the old spelling reads as another config");
        assert_eq!(b.excitation.kind.as_str(), kind);
        b.validate(p).unwrap();
        let f = dir.path().join(format!("old-{kind}.toml"));
        std::fs::write(&f, &old).unwrap();
        let o = common::run(&["config", "check", f.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{kind}: {err}");
        assert!(
            err.contains(&format!(
                "{}: chirp.kind is deprecated: write [excitation] kind = \"{kind}\"",
                f.display()
            )),
            "{kind}: {err}"
        );
        // The new spelling: no warning.
        let f = dir.path().join(format!("new-{kind}.toml"));
        std::fs::write(&f, &with_new).unwrap();
        let o = common::run(&["config", "check", f.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.success() && !err.contains("deprecated"),
            "{kind}: {err}"
        );
    }
    // Both spellings: refused, naming the old key.
    let both = new.replacen("[chirp]\n", "[chirp]\nkind = \"linear\"\n", 1);
    let f = dir.path().join("both.toml");
    std::fs::write(&f, &both).unwrap();
    let o = common::run(&["config", "check", f.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("chirp.kind: is the old spelling of excitation.kind"),
        "{err}"
    );
    // A value no kind has, in the old spelling: refused, naming the kind.
    let bad = format!(
        "{}[chirp]\nkind = \"sine\"\n{}",
        &new[..block_start],
        &new[block_end + "[chirp]\n".len()..]
    );
    let f = dir.path().join("bad.toml");
    std::fs::write(&f, &bad).unwrap();
    let o = common::run(&["config", "check", f.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("kind") && err.contains("sine"), "{err}");
}
