//! The independent loop-margin reference: `tests/data/loop_reference.py`
//! (python-control 0.10, numpy, scipy) run on [`Case`]s, its answers as
//! [`RefMargins`].
//!
//! A case is a bench's plant and actuator, its loop rate, a
//! `[controller.NAME]` and the computation delay; the script builds the
//! loop `L(s) = C(s) · u · k_f · G(s) · A(s) · H(s) · e^{−sτ}` from scratch
//! (its header has the formulas and sources) and reports the crossovers
//! with their phase margins, the gain margin, the modulus margin
//! (‖S‖∞), the sensitivity bandwidth ω_B and the closed-loop stability.
//!
//! Python is `$BENCH_PYTHON` when set (`.ci/run` points it at a venv),
//! else `python3`. A missing interpreter or module is a test failure with
//! the command that installs it, never a skip: a design that the reference
//! cannot check is not checked.

use bench::config::{BenchConfig, ControllerConfig};
use bench_plant::model::Sr4dofParams;
use bench_plant::sim::ActuatorParams;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::process::Command;

/// How to get what the reference needs, for failure messages.
pub const INSTALL_HINT: &str = "the loop reference tests/data/loop_reference.py needs python3 with numpy, scipy and python-control 0.10: `pip install 'control>=0.10,<0.11'` (brings numpy and scipy; in a venv where pip refuses with externally-managed-environment, then set BENCH_PYTHON=<venv>/bin/python), or run .ci/run, which does that";

/// One loop for the reference: the input object of `loop_reference.py`.
#[derive(Debug, Clone, Serialize)]
pub struct Case {
    /// Shown in tables and messages.
    pub name: String,
    /// The `[plant]` table (its `disturbance` is ignored).
    pub plant: Sr4dofParams,
    /// The `[actuator]` table (force constant and amplifier bandwidth).
    pub actuator: ActuatorParams,
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Computation delay τ between the sample and the command, s.
    pub computation_delay_s: f64,
    /// The link's pure delay d, whole loop periods (`e^{−sdT}`; sampled
    /// `z^{−d}`): 1 for EtherCAT's process data.
    pub link_delay_periods: u32,
    /// The controller as designed (continuous; its `discretization` is
    /// ignored: the reference checks the design).
    pub controller: ControllerConfig,
    /// Zero-order hold `(1 − e^{−sT})/(sT)` in the loop.
    pub hold: bool,
    /// Current amplifier `ω_a/(s + ω_a)` in the loop.
    pub amplifier: bool,
    /// Also the margins of the sampled loop ([`RefMargins::discrete`]);
    /// doubles the time.
    pub discrete_margins: bool,
}

impl Case {
    /// The loop that runs on `cfg`'s bench: `controller` with the zero-order
    /// hold, the amplifier and `computation_delay_s`, at `cfg.loop_.rate_hz`.
    pub fn new(
        name: impl Into<String>,
        cfg: &BenchConfig,
        controller: &ControllerConfig,
        computation_delay_s: f64,
    ) -> Self {
        Self {
            name: name.into(),
            plant: cfg.plant,
            actuator: cfg.actuator,
            rate_hz: cfg.loop_.rate_hz,
            computation_delay_s,
            link_delay_periods: 0,
            controller: controller.clone(),
            hold: true,
            amplifier: true,
            discrete_margins: false,
        }
    }

    /// As the thesis computed the margins (§6.2.1): continuous, no hold,
    /// no amplifier, no computation delay (`k_f G(s) C(s)` alone).
    pub fn thesis(mut self) -> Self {
        self.hold = false;
        self.amplifier = false;
        self.computation_delay_s = 0.0;
        self.link_delay_periods = 0;
        self
    }

    /// With the link's pure delay of `periods` loop periods.
    pub fn with_link_delay(mut self, periods: u32) -> Self {
        self.link_delay_periods = periods;
        self
    }

    /// With the margins of the sampled loop too.
    pub fn with_discrete_margins(mut self) -> Self {
        self.discrete_margins = true;
        self
    }
}

/// The figures of one open loop `L(jω)` (Skogestad & Postlethwaite §2.4).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefLoop {
    /// Every gain crossover |L| = 1, rad/s, ascending.
    pub crossovers_rad_s: Vec<f64>,
    /// Phase margin at each crossover, degrees in (−180, 180].
    pub phase_margins_deg: Vec<f64>,
    /// Every crossing of the negative real axis, rad/s, ascending.
    pub phase_crossovers_rad_s: Vec<f64>,
    /// `−20 log10 |L|` at each phase crossover, dB.
    pub gain_margins_db: Vec<f64>,
    /// The smallest of those with |L| < 1, dB (`None`: none).
    pub gain_margin_db: Option<f64>,
    /// Where, rad/s.
    pub gain_margin_at_rad_s: Option<f64>,
    /// ‖S‖∞ = max |1/(1 + L)|.
    pub sensitivity_peak: f64,
    /// Where, rad/s.
    pub sensitivity_peak_at_rad_s: f64,
    /// Modulus margin, 1/‖S‖∞: the least distance from L to −1.
    pub modulus_margin: f64,
    /// Sensitivity bandwidth ω_B: the lowest frequency where |S| reaches
    /// 1/√2 (−3 dB) from below, rad/s (`None`: never).
    pub sensitivity_bandwidth_rad_s: Option<f64>,
}

/// The reference's answer for one [`Case`].
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefMargins {
    /// The case's name.
    pub name: String,
    /// The continuous loop, with the hold exact, as the case asks.
    #[serde(flatten)]
    pub margins: RefLoop,
    /// Order of the Padé approximant of the delay `T/2 + τ` (0: none).
    pub pade_order: u32,
    /// That delay, s.
    pub pade_delay_s: f64,
    /// Largest real part of the closed-loop poles with the Padé delay,
    /// rad/s.
    pub largest_real_part_rad_s: f64,
    /// All those poles in the open left half plane.
    pub stable_continuous_pade: bool,
    /// Largest |z| of the sampled closed loop (`None` without the hold).
    pub largest_pole_magnitude: Option<f64>,
    /// All sampled closed-loop poles inside the unit circle (`None`
    /// without the hold).
    pub stable_discrete: Option<bool>,
    /// Margins of the sampled loop (ZOH plant, Tustin controller, `z^{−k}`
    /// delay), when [`Case::discrete_margins`] asked for them.
    pub discrete: Option<RefLoop>,
}

/// What a loop must meet (issue 27's defaults: [`Requirements::issue_27`]).
#[derive(Debug, Clone, Copy)]
pub struct Requirements {
    /// Least phase margin at every crossover, degrees.
    pub min_phase_margin_deg: f64,
    /// Least gain margin, dB.
    pub min_gain_margin_db: f64,
    /// Largest ‖S‖∞.
    pub max_sensitivity_peak: f64,
}

impl Requirements {
    /// Phase margin ≥ 40° at every crossover, gain margin ≥ 6 dB,
    /// ‖S‖∞ ≤ 2 (a 6 dB modulus margin).
    pub fn issue_27() -> Self {
        Self {
            min_phase_margin_deg: 40.0,
            min_gain_margin_db: 6.0,
            max_sensitivity_peak: 2.0,
        }
    }
}

impl RefMargins {
    /// Stable by every check the reference ran (Padé and, with the hold,
    /// the sampled loop).
    pub fn stable(&self) -> bool {
        self.stable_continuous_pade && self.stable_discrete.unwrap_or(true)
    }

    /// What the loop fails of `req`, one line each (empty: it meets them).
    pub fn violations(&self, req: &Requirements) -> Vec<String> {
        let m = &self.margins;
        let mut v = Vec::new();
        if !self.stable_continuous_pade {
            v.push(format!(
                "{}: closed loop unstable (continuous, Padé order {}): largest real part {:.3} rad/s",
                self.name, self.pade_order, self.largest_real_part_rad_s
            ));
        }
        if self.stable_discrete == Some(false) {
            v.push(format!(
                "{}: closed loop unstable (sampled): largest |z| = {:.5}",
                self.name,
                self.largest_pole_magnitude.unwrap_or(f64::NAN)
            ));
        }
        if m.crossovers_rad_s.is_empty() {
            v.push(format!("{}: no gain crossover", self.name));
        }
        // The phase margin at a crossover is the angle between L and −1
        // whichever way L turns: |PM| (a crossing at ∠L = +80° is 100°
        // from −1; the Nyquist count, not the sign, says it is stable).
        for (w, pm) in m.crossovers_rad_s.iter().zip(&m.phase_margins_deg) {
            if pm.abs() < req.min_phase_margin_deg {
                v.push(format!(
                    "{}: phase margin {pm:.1}° at the crossover {w:.1} rad/s is below {}°",
                    self.name, req.min_phase_margin_deg
                ));
            }
        }
        if let (Some(gm), Some(at)) = (m.gain_margin_db, m.gain_margin_at_rad_s) {
            if gm < req.min_gain_margin_db {
                v.push(format!(
                    "{}: gain margin {gm:.2} dB at {at:.1} rad/s is below {} dB",
                    self.name, req.min_gain_margin_db
                ));
            }
        }
        if m.sensitivity_peak > req.max_sensitivity_peak {
            v.push(format!(
                "{}: ‖S‖∞ = {:.3} at {:.1} rad/s is above {} (modulus margin {:.3})",
                self.name,
                m.sensitivity_peak,
                m.sensitivity_peak_at_rad_s,
                req.max_sensitivity_peak,
                m.modulus_margin
            ));
        }
        v
    }
}

/// The interpreter: `$BENCH_PYTHON`, else `python3`.
pub fn python() -> String {
    std::env::var("BENCH_PYTHON")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "python3".to_string())
}

#[derive(Deserialize)]
struct Output {
    cases: Vec<RefMargins>,
}

/// Runs `tests/data/loop_reference.py` on `cases`; the answers in the same
/// order.
///
/// # Panics
/// When python or its modules are missing (with [`INSTALL_HINT`]), when
/// the script fails, or when its output does not parse: every one a test
/// failure, never a skip.
pub fn python_reference(cases: &[Case]) -> Vec<RefMargins> {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = dir.path().join("cases.json");
    let output = dir.path().join("reference.json");
    std::fs::write(
        &input,
        serde_json::to_vec(&serde_json::json!({ "cases": cases })).expect("cases as JSON"),
    )
    .expect("write the cases");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/loop_reference.py");
    let py = python();
    let out = Command::new(&py)
        .arg(&script)
        .arg(&input)
        .arg(&output)
        .output()
        .unwrap_or_else(|e| panic!("cannot run `{py}` ({e}): {INSTALL_HINT}"));
    assert!(
        out.status.success(),
        "`{py} {}` failed ({}):\n{}\n{INSTALL_HINT}",
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&output).expect("the reference's output");
    let parsed: Output = serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("the reference's output does not parse ({e}):\n{text}"));
    assert_eq!(parsed.cases.len(), cases.len());
    parsed.cases
}
