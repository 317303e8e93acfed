//! The simulated bench: the SR4DoF model ([`crate::model`]) behind a
//! first-order current amplifier and a capacitance probe, discretised
//! exactly at the loop period.
//!
//! State `x = [z (4), ż (4), i]` (m, m/s, A), inputs `w = [u, d]`: the
//! current demand `u` (A, clipped at the amplifier's peak current) and an
//! input force disturbance `d` (N, acting where the actuator acts).
//!
//! ```text
//! ż = v
//! M v̇ = −K z − C v + q (k_f i + d)
//! i̇ = ω_a (u − i),        ω_a = 2π · bandwidth_hz        (first-order current loop)
//! ```
//!
//! Zero-order hold, exact: `[Φ Γ; 0 I] = exp([A B; 0 0] · T)`, so
//! `x[k+1] = Φ x[k] + Γ w[k]` reproduces the continuous plant at the sample
//! instants for a command held over each period.
//!
//! The probe adds white Gaussian noise (`noise_rms_m`), quantises to
//! `quantization_m`, saturates at `±range_m` and raises
//! [`SampleFlags::out_of_range`] beyond it. A mechanical stop at
//! `±mechanical_stop_m` holds `x1` (inelastic: the X velocity of stage ①
//! into the stop is removed). Noise comes from a ChaCha8 generator seeded
//! from the config: the same config and seed give the same samples, bit for
//! bit.
//!
//! Layer rule: may use `model`.

mod response;

use crate::model::{Sr4dof, Sr4dofParams};
use bench_hal::param::{positive, ParamError};
use bench_hal::{
    Clock, Command, DeviceInfo, ErrorKind, LifecycleError, Sample, SampleFlags, Stage,
};
use nalgebra::{Complex, DMatrix, SMatrix, SVector};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use response::HessenbergResponse;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Number of continuous states: 4 positions, 4 velocities, 1 coil current.
pub const STATES: usize = 9;

/// Current amplifier and voice-coil actuator (the `[actuator]` table).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorParams {
    /// Voice-coil force constant `k_f`, N/A (LA24-20-000A: 11.12).
    pub force_constant_n_per_a: f64,
    /// −3 dB bandwidth of the amplifier's current loop, Hz (thesis: 1 kHz).
    pub bandwidth_hz: f64,
    /// Peak current, A: demands beyond are clipped by the amplifier.
    pub peak_current_a: f64,
    /// Continuous current rating, A (I²t limit).
    pub continuous_current_a: f64,
    /// The coil's rated peak current from its datasheet, A: the peak
    /// force over the force constant the datasheet gives (LA24-20-000A:
    /// 111 N / 11.12 N/A = 9.98 A, thesis §5.1.2). `peak_current_a` may not
    /// exceed it. Absent in the TOML: the thesis coil's 9.98 A.
    #[serde(default = "ActuatorParams::la24_rated_peak_current_a")]
    pub rated_peak_current_a: f64,
    /// The coil's rated continuous current from its datasheet, A: the
    /// continuous (stall) force over the force constant (LA24-20-000A:
    /// 26 N / 11.12 N/A = 2.34 A). `continuous_current_a` may not exceed
    /// it. Absent in the TOML: the thesis coil's 2.34 A.
    #[serde(default = "ActuatorParams::la24_rated_continuous_current_a")]
    pub rated_continuous_current_a: f64,
}

impl ActuatorParams {
    /// The thesis coil's (BEI Kimco LA24-20-000A) rated peak current, A.
    pub fn la24_rated_peak_current_a() -> f64 {
        9.98
    }

    /// The thesis coil's rated continuous current, A.
    pub fn la24_rated_continuous_current_a() -> f64 {
        2.34
    }

    /// Checks every value, keys under `prefix`.
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        positive(
            &format!("{prefix}.force_constant_n_per_a"),
            self.force_constant_n_per_a,
        )?;
        positive(&format!("{prefix}.bandwidth_hz"), self.bandwidth_hz)?;
        positive(&format!("{prefix}.peak_current_a"), self.peak_current_a)?;
        positive(
            &format!("{prefix}.continuous_current_a"),
            self.continuous_current_a,
        )?;
        positive(
            &format!("{prefix}.rated_peak_current_a"),
            self.rated_peak_current_a,
        )?;
        positive(
            &format!("{prefix}.rated_continuous_current_a"),
            self.rated_continuous_current_a,
        )?;
        if self.continuous_current_a > self.peak_current_a {
            return Err(ParamError::new(
                format!("{prefix}.continuous_current_a"),
                format!(
                    "{} A is above peak_current_a = {} A",
                    self.continuous_current_a, self.peak_current_a
                ),
            ));
        }
        Ok(())
    }
}

/// Position probe (the `[probe]` table).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeParams {
    /// Half range: the probe reads `[-range_m, +range_m]`, m (2 mm probe: 1e-3).
    pub range_m: f64,
    /// White noise, RMS, m (thesis probe: 40 nm).
    pub noise_rms_m: f64,
    /// Quantisation step, m (0 for none).
    pub quantization_m: f64,
}

impl ProbeParams {
    /// Checks every value, keys under `prefix`.
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        positive(&format!("{prefix}.range_m"), self.range_m)?;
        bench_hal::param::non_negative(&format!("{prefix}.noise_rms_m"), self.noise_rms_m)?;
        bench_hal::param::non_negative(&format!("{prefix}.quantization_m"), self.quantization_m)?;
        Ok(())
    }
}

/// Everything the simulated bench needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimParams {
    /// The mechanism.
    pub plant: Sr4dofParams,
    /// Amplifier and actuator.
    pub actuator: ActuatorParams,
    /// Probe.
    pub probe: ProbeParams,
    /// Mechanical stop on x1, m (travel blocked beyond ±this).
    pub mechanical_stop_m: f64,
    /// Seed of the noise generator.
    pub seed: u64,
}

/// Errors of the simulated backend.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// A parameter is unusable.
    #[error("invalid simulator parameter {0}")]
    Param(#[from] ParamError),
    /// Used against the stage's lifecycle.
    #[error("simulated stage: {0}")]
    Lifecycle(#[from] bench_hal::LifecycleError),
    /// A sample period the simulator cannot use.
    #[error("sample period {period_ns} ns is unusable: {reason}")]
    Period {
        /// The requested period, ns.
        period_ns: u64,
        /// Why.
        reason: String,
    },
}

impl bench_hal::Error for SimError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Param(_) | Self::Period { .. } => ErrorKind::Config,
            Self::Lifecycle(e) => bench_hal::Error::kind(e),
        }
    }
}

/// The plant (mechanics + amplifier) discretised with a zero-order hold.
#[derive(Debug, Clone)]
pub struct ZohPlant {
    /// State transition `Φ = e^{A T}`.
    pub phi: SMatrix<f64, STATES, STATES>,
    /// Input matrix `Γ = ∫₀ᵀ e^{A τ} dτ B`, columns `[u (A), d (N)]`.
    pub gamma: SMatrix<f64, STATES, 2>,
    /// Sample period, s.
    pub period_s: f64,
    /// Continuous state matrix `A`.
    pub a: SMatrix<f64, STATES, STATES>,
    /// Continuous input matrix `B`, columns `[u (A), d (N)]`.
    pub b: SMatrix<f64, STATES, 2>,
    /// `x1 / u` of `Φ, Γ_u`, reduced once for [`Self::frf`].
    sampled_response: HessenbergResponse<STATES>,
    /// `x1 / u` of `A, B_u`, reduced once for [`Self::frf_continuous`].
    continuous_response: HessenbergResponse<STATES>,
}

impl ZohPlant {
    /// Builds `A`, `B` from the model and the amplifier and discretises them
    /// exactly (matrix exponential of the augmented matrix).
    pub fn new(model: &Sr4dof, actuator: &ActuatorParams, period_s: f64) -> Self {
        Self::build(model, actuator, period_s, true)
    }

    /// The same plant with an ideal amplifier (coil current = demand, no
    /// lag): the force enters directly as `k_f u`. The current state is kept
    /// (so the matrices keep their size) but decoupled, with a stable
    /// eigenvalue `e^{−T}`.
    pub fn without_amplifier_lag(model: &Sr4dof, actuator: &ActuatorParams, period_s: f64) -> Self {
        Self::build(model, actuator, period_s, false)
    }

    fn build(model: &Sr4dof, actuator: &ActuatorParams, period_s: f64, lag: bool) -> Self {
        let m_inv = model
            .mass()
            .try_inverse()
            .expect("the model checked M positive definite");
        let mk = -m_inv * model.stiffness();
        let mc = -m_inv * model.damping();
        let mq = m_inv * model.input();
        let wa = 2.0 * PI * actuator.bandwidth_hz;
        let mut a = SMatrix::<f64, STATES, STATES>::zeros();
        let mut b = SMatrix::<f64, STATES, 2>::zeros();
        for i in 0..4 {
            a[(i, 4 + i)] = 1.0;
            for j in 0..4 {
                a[(4 + i, j)] = mk[(i, j)];
                a[(4 + i, 4 + j)] = mc[(i, j)];
            }
            if lag {
                a[(4 + i, 8)] = mq[i] * actuator.force_constant_n_per_a;
            } else {
                b[(4 + i, 0)] = mq[i] * actuator.force_constant_n_per_a;
            }
            b[(4 + i, 1)] = mq[i];
        }
        if lag {
            a[(8, 8)] = -wa;
            b[(8, 0)] = wa;
        } else {
            a[(8, 8)] = -1.0;
        }

        let n = STATES + 2;
        let mut aug = DMatrix::<f64>::zeros(n, n);
        for i in 0..STATES {
            for j in 0..STATES {
                aug[(i, j)] = a[(i, j)] * period_s;
            }
            for j in 0..2 {
                aug[(i, STATES + j)] = b[(i, j)] * period_s;
            }
        }
        let e = aug.exp();
        let phi = SMatrix::<f64, STATES, STATES>::from_fn(|i, j| e[(i, j)]);
        let gamma = SMatrix::<f64, STATES, 2>::from_fn(|i, j| e[(i, STATES + j)]);
        let x1 = SVector::<f64, STATES>::from_fn(|i, _| if i == 0 { 1.0 } else { 0.0 });
        Self {
            phi,
            gamma,
            period_s,
            a,
            b,
            sampled_response: HessenbergResponse::new(phi, gamma.column(0).into_owned(), x1),
            continuous_response: HessenbergResponse::new(a, b.column(0).into_owned(), x1),
        }
    }

    /// One step: `x ← Φ x + Γ [u, d]ᵀ`. Real-time safe (no allocation).
    #[inline]
    pub fn step(&self, x: &mut SVector<f64, STATES>, current_a: f64, force_n: f64) {
        let w = SVector::<f64, 2>::new(current_a, force_n);
        *x = self.phi * *x + self.gamma * w;
    }

    /// Frequency response of the sampled system from the current demand `u`
    /// to `x1`: `cᵀ (z I − Φ)⁻¹ Γ_u` at `z = e^{jωT}`, m/A. This is what a
    /// sampled measurement of the ZOH plant converges to; it differs from the
    /// continuous response by the hold's half-period delay and aliasing.
    pub fn frf(&self, frequency_hz: f64) -> Complex<f64> {
        let w = 2.0 * PI * frequency_hz * self.period_s;
        self.sampled_response.at(Complex::new(w.cos(), w.sin()))
    }

    /// Continuous frequency response from the current demand to `x1`,
    /// `cᵀ (jωI − A)⁻¹ B_u`, m/A (amplifier lag included, no hold).
    pub fn frf_continuous(&self, frequency_hz: f64) -> Complex<f64> {
        self.continuous_response
            .at(Complex::new(0.0, 2.0 * PI * frequency_hz))
    }
}

/// A fault the simulated device can be told to produce (tests and
/// `bench control --inject-fault`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FaultInjection {
    /// The probe reads NaN from then on.
    Nan,
    /// The device repeats its last sample (same sequence number and value)
    /// from then on.
    Frozen,
    /// The device drops this many samples once (a sequence gap; the plant
    /// keeps moving).
    Drop(u64),
    /// The reading jumps by this offset, m, from then on.
    Jump(f64),
    /// The probe reports out of range from then on.
    OutOfRange,
    /// The probe's electronics died from then on: it reads 0 m (0 V at
    /// the acquisition), without noise, while the sequence advances, the
    /// device flagging nothing (what an analog input shows of a dead
    /// probe).
    Dead,
    /// The probe no longer sees the stage from then on (its target came
    /// loose): it reads its own noise around the reading it had, while the
    /// sequence advances and the stage moves.
    Blind,
    /// The host stalls once for this long, s: the read blocks (the
    /// calling thread sleeps), as a host that was not scheduled would
    /// (tests of the loop's stall rules; the plant advances one period per
    /// read, so nothing physical happens in the simulation).
    Stall(f64),
}

/// A fault scheduled at a device time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledFault {
    /// Device time at which it starts, s.
    pub at_s: f64,
    /// What happens.
    pub kind: FaultInjection,
}

/// Second-order section (RBJ cookbook, bilinear) for the disturbance
/// shaping filter, direct form I.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
    x: [f64; 2],
    y: [f64; 2],
}

impl Biquad {
    /// Butterworth (Q = 1/√2) low-pass (`high_pass = false`) or high-pass
    /// at `f_hz` for sample rate `fs_hz`.
    fn butterworth(f_hz: f64, fs_hz: f64, high_pass: bool) -> Self {
        let w0 = 2.0 * PI * (f_hz / fs_hz).min(0.49);
        let alpha = w0.sin() / (2.0 * std::f64::consts::FRAC_1_SQRT_2);
        let c = w0.cos();
        let a0 = 1.0 + alpha;
        let b = if high_pass {
            [(1.0 + c) / 2.0, -(1.0 + c), (1.0 + c) / 2.0]
        } else {
            [(1.0 - c) / 2.0, 1.0 - c, (1.0 - c) / 2.0]
        };
        Self {
            b: [b[0] / a0, b[1] / a0, b[2] / a0],
            a: [-2.0 * c / a0, (1.0 - alpha) / a0],
            ..Default::default()
        }
    }

    #[inline]
    fn step(&mut self, x: f64) -> f64 {
        let y = self.b[0] * x + self.b[1] * self.x[0] + self.b[2] * self.x[1]
            - self.a[0] * self.y[0]
            - self.a[1] * self.y[1];
        self.x = [x, self.x[0]];
        self.y = [y, self.y[0]];
        y
    }
}

/// Band-limited Gaussian force generator with its own random stream.
#[derive(Debug, Clone)]
struct DisturbanceSource {
    hp: Biquad,
    lp: Biquad,
    scale: f64,
    rng: ChaCha8Rng,
}

impl DisturbanceSource {
    fn new(d: &crate::model::Disturbance, fs_hz: f64, seed: u64) -> Self {
        let hp = Biquad::butterworth(d.band_hz[0], fs_hz, true);
        let lp = Biquad::butterworth(d.band_hz[1], fs_hz, false);
        // Noise gain of the shaping filter: energy of its impulse response.
        let (mut h, mut l) = (hp, lp);
        let mut energy = 0.0;
        let n = (50.0 * fs_hz / d.band_hz[0]).min(5e7) as usize;
        for k in 0..n.max(1000) {
            let v = l.step(h.step(if k == 0 { 1.0 } else { 0.0 }));
            energy += v * v;
        }
        Self {
            hp,
            lp,
            scale: if energy > 0.0 {
                d.rms_n / energy.sqrt()
            } else {
                0.0
            },
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xD157_0EBA_5CE0_F00D),
        }
    }

    /// As [`Self::new`] with `seed`, without recomputing the gain: the
    /// filter at rest, the generator fresh.
    fn reseed(&mut self, seed: u64) {
        for f in [&mut self.hp, &mut self.lp] {
            f.x = [0.0; 2];
            f.y = [0.0; 2];
        }
        self.rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD157_0EBA_5CE0_F00D);
    }

    #[inline]
    fn next_n(&mut self) -> f64 {
        let w: f64 = StandardNormal.sample(&mut self.rng);
        self.scale * self.lp.step(self.hp.step(w))
    }
}

/// The simulated stage backend.
#[derive(Debug, Clone)]
pub struct SimStage {
    params: SimParams,
    model: Sr4dof,
    plant: Option<ZohPlant>,
    x: SVector<f64, STATES>,
    rng: ChaCha8Rng,
    seq: u64,
    period_ns: u64,
    enabled: bool,
    demand_a: f64,
    first_read: bool,
    at_stop: bool,
    fault: Option<ScheduledFault>,
    drop_done: bool,
    last_sample: Option<Sample>,
    disturbance: Option<DisturbanceSource>,
    /// A [`SimStage::reseed`] that takes effect at the next sample.
    reseed_at_next: Option<u64>,
    /// Where a [`FaultInjection::Blind`] probe stays, m.
    blind_at_m: Option<f64>,
}

impl SimStage {
    /// Builds the model and validates the parameters. The stage starts
    /// unconfigured, at rest at the operating point.
    ///
    /// # Errors
    /// [`SimError::Param`] naming the offending key.
    pub fn new(params: SimParams) -> Result<Self, SimError> {
        params.actuator.validate("actuator")?;
        params.probe.validate("probe")?;
        positive("stage.mechanical_stop_m", params.mechanical_stop_m)?;
        let model = Sr4dof::new(params.plant)?;
        Ok(Self {
            rng: ChaCha8Rng::seed_from_u64(params.seed),
            params,
            model,
            plant: None,
            x: SVector::zeros(),
            seq: 0,
            period_ns: 0,
            enabled: false,
            demand_a: 0.0,
            first_read: true,
            at_stop: false,
            fault: None,
            drop_done: false,
            last_sample: None,
            disturbance: None,
            reseed_at_next: None,
            blind_at_m: None,
        })
    }

    /// The lumped model behind the simulator.
    pub fn model(&self) -> &Sr4dof {
        &self.model
    }

    /// The parameters.
    pub fn params(&self) -> &SimParams {
        &self.params
    }

    /// The discretised plant, once configured.
    pub fn plant(&self) -> Option<&ZohPlant> {
        self.plant.as_ref()
    }

    /// Current through the coil, A (the amplifier's output state).
    pub fn coil_current_a(&self) -> f64 {
        self.x[8]
    }

    /// True position of stage ① in X, m (no probe noise).
    pub fn true_position_m(&self) -> f64 {
        self.x[0]
    }

    /// Whether the amplifier is enabled.
    pub fn is_enabled(&self) -> bool {
        self.enabled
    }

    /// Restarts the noise from `seed`, as in a stage created with it, from
    /// the next sample on: that sample carries the first probe-noise draw
    /// of a fresh generator, and the period after it the first draw of the
    /// disturbance force, whose shaping filter starts at rest. A local run
    /// (a stage just created) draws them at the same samples, so a job that
    /// starts with a reseed on a stage at rest records what a local run
    /// with that seed records, sample for sample. The mechanical state,
    /// the device clock and scheduled faults are kept: the stage moves on
    /// from where it is. Allocates nothing (the daemon's real-time thread
    /// calls it as a job takes over).
    pub fn reseed(&mut self, seed: u64) {
        self.reseed_at_next = Some(seed);
    }

    /// Schedules a fault (replaces any earlier one).
    pub fn inject(&mut self, fault: ScheduledFault) {
        self.fault = Some(fault);
        self.drop_done = false;
        self.blind_at_m = None;
    }

    /// The injected fault in force at this sample. A drop or a jump is an
    /// event *between* two samples: one scheduled at or before the first
    /// sample happens right after it (a gap or a jump needs a sample before
    /// it to be one; at 0 s there is none, and the first sample would
    /// simply start later or elsewhere).
    fn active_fault(&self) -> Option<FaultInjection> {
        let f = self.fault?;
        let t = self.seq as f64 * self.period_ns as f64 * 1e-9;
        let event = matches!(
            f.kind,
            FaultInjection::Drop(_) | FaultInjection::Jump(_) | FaultInjection::Stall(_)
        );
        (t >= f.at_s && !(event && self.last_sample.is_none())).then_some(f.kind)
    }

    fn advance(&mut self) {
        let Some(plant) = self.plant.as_ref() else {
            return;
        };
        let demand = if self.enabled { self.demand_a } else { 0.0 };
        let d = self.disturbance.as_mut().map_or(0.0, |s| s.next_n());
        plant.step(&mut self.x, demand, d);
        if !self.enabled {
            // A disabled amplifier opens the coil circuit: no current flows.
            self.x[8] = 0.0;
        }
        let stop = self.params.mechanical_stop_m;
        self.at_stop = false;
        if self.x[0].abs() > stop {
            self.x[0] = stop.copysign(self.x[0]);
            if self.x[4] * self.x[0] > 0.0 {
                self.x[4] = 0.0;
            }
            self.at_stop = true;
        }
    }

    /// Device time of the latest sample, s since `configure` (fault
    /// injections are scheduled on this clock).
    pub fn device_time_s(&self) -> f64 {
        self.seq as f64 * self.period_ns as f64 * 1e-9
    }

    /// Whether x1 sat on the mechanical stop during the last period.
    pub fn at_stop(&self) -> bool {
        self.at_stop
    }
}

impl Stage for SimStage {
    type Error = SimError;

    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, SimError> {
        // 10 µs … 1 s: faster than the matrix exponential stays accurate for
        // and slower than any sensible loop are both refused.
        if !(10_000..=1_000_000_000).contains(&period_ns) {
            return Err(SimError::Period {
                period_ns,
                reason: "must be between 10 µs and 1 s".into(),
            });
        }
        self.plant = Some(ZohPlant::new(
            &self.model,
            &self.params.actuator,
            period_ns as f64 * 1e-9,
        ));
        self.period_ns = period_ns;
        self.disturbance = self
            .params
            .plant
            .disturbance
            .filter(|d| d.rms_n > 0.0)
            .map(|d| DisturbanceSource::new(&d, 1e9 / period_ns as f64, self.params.seed));
        self.seq = 0;
        self.first_read = true;
        self.enabled = false;
        self.demand_a = 0.0;
        Ok(DeviceInfo {
            name: "sim:sr4dof".into(),
            clock: Clock::Host,
            period_ns,
            peak_current_a: self.params.actuator.peak_current_a,
            continuous_current_a: self.params.actuator.continuous_current_a,
            probe_range_m: self.params.probe.range_m,
            probe_lsb_m: 0.0,
            watchdog_s: None,
        })
    }

    fn enable(&mut self) -> Result<(), SimError> {
        if self.plant.is_none() {
            return Err(LifecycleError::NotConfigured.into());
        }
        self.enabled = true;
        self.demand_a = 0.0;
        Ok(())
    }

    fn read_sample(&mut self) -> Result<Sample, SimError> {
        if self.plant.is_none() {
            return Err(LifecycleError::NotConfigured.into());
        }
        // The plant evolves over the period that ends at this sample, with
        // the command written after the previous sample held (ZOH).
        if self.first_read {
            self.first_read = false;
        } else {
            self.advance();
            self.seq += 1;
        }
        if let Some(seed) = self.reseed_at_next.take() {
            // The period that ended at this sample ran on the old noise.
            self.params.seed = seed;
            self.rng = ChaCha8Rng::seed_from_u64(seed);
            if let Some(d) = self.disturbance.as_mut() {
                d.reseed(seed);
            }
        }
        let fault = self.active_fault();
        if let (Some(FaultInjection::Frozen), Some(last)) = (fault, self.last_sample) {
            return Ok(last);
        }
        if let (Some(FaultInjection::Stall(s)), false) = (fault, self.drop_done) {
            self.drop_done = true;
            if s.is_finite() && s > 0.0 {
                std::thread::sleep(std::time::Duration::from_secs_f64(s));
            }
        }
        if let (Some(FaultInjection::Drop(n)), false) = (fault, self.drop_done) {
            self.drop_done = true;
            for _ in 0..n {
                self.advance();
                self.seq += 1;
            }
        }
        let p = &self.params.probe;
        let noise: f64 = StandardNormal.sample(&mut self.rng);
        let offset = match fault {
            Some(FaultInjection::Jump(dx)) => dx,
            _ => 0.0,
        };
        let seen_m = if fault == Some(FaultInjection::Blind) {
            *self.blind_at_m.get_or_insert(self.x[0])
        } else {
            self.x[0]
        };
        let mut y = seen_m + offset + p.noise_rms_m * noise;
        if p.quantization_m > 0.0 {
            y = (y / p.quantization_m).round() * p.quantization_m;
        }
        // A full-scale (saturated) reading counts as out of range.
        let mut out_of_range = y.abs() >= p.range_m || fault == Some(FaultInjection::OutOfRange);
        if out_of_range {
            y = p.range_m.copysign(y);
        }
        if fault == Some(FaultInjection::Nan) {
            y = f64::NAN;
            out_of_range = false;
        }
        if fault == Some(FaultInjection::Dead) {
            y = 0.0;
            out_of_range = false;
        }
        let sample = Sample {
            seq: self.seq,
            device_time_ns: self.seq * self.period_ns,
            position_m: y,
            measured_current_a: self.x[8],
            flags: SampleFlags {
                out_of_range,
                amplifier_enabled: self.enabled,
                amplifier_fault: false,
                // Commands are applied in the call: never late.
                command_late: false,
            },
        };
        self.last_sample = Some(sample);
        Ok(sample)
    }

    fn write_command(&mut self, command: Command) -> Result<(), SimError> {
        let i = command.current_a;
        if let Err(e) = LifecycleError::check_command(self.plant.is_some(), self.enabled, i) {
            if matches!(e, LifecycleError::NotFinite { .. }) {
                self.demand_a = 0.0;
            }
            return Err(e.into());
        }
        let peak = self.params.actuator.peak_current_a;
        self.demand_a = i.clamp(-peak, peak);
        Ok(())
    }

    fn disable(&mut self) -> Result<(), SimError> {
        self.enabled = false;
        self.demand_a = 0.0;
        self.x[8] = 0.0;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Disturbance;

    /// The shaped disturbance has the configured RMS, zero mean, and its
    /// power sits in the band (a 2nd-order Butterworth band-pass: the
    /// variance of first differences is bounded by the high edge).
    #[test]
    fn disturbance_rms_and_band() {
        let d = Disturbance {
            rms_n: 0.02,
            band_hz: [1.0, 30.0],
        };
        let fs = 5000.0;
        let mut src = DisturbanceSource::new(&d, fs, 9);
        let n = 2_000_000;
        let v: Vec<f64> = (0..n).map(|_| src.next_n()).collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        assert!((rms / 0.02 - 1.0).abs() < 0.05, "{rms}");
        assert!(mean.abs() < 0.1 * 0.02, "{mean}");
        // For a signal band-limited to f_h, RMS of the first difference is
        // at most about 2π f_h T × RMS; white noise would give √2 × RMS.
        let diff = (v.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>() / n as f64).sqrt();
        assert!(diff < 2.0 * PI * 30.0 / fs * 0.02 * 1.5, "{diff}");
    }
}
