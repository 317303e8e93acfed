//! The bounds of the safety keys (`[safety]`, `[actuator]`, `[emulator]`
//! and the link timeouts of `[backend]`), with why each is where it is.
//! [`super::BenchConfig::check`] refuses a value outside its range, naming the key;
//! the README's configuration reference and the comments in
//! `bench-config/*.toml` give the same ranges.
//!
//! [`ranges`] holds the bounds of the other keys, with their reasons.

/// Largest `[emulator] watchdog_ms`, ms: a host that dies leaves the
/// current flowing at most this long (plus one period).
pub const WATCHDOG_MAX_MS: f64 = 1000.0;
/// Smallest `[emulator] watchdog_ms`, ms (the serial hello announces it
/// in whole ms). It must also cover two loop periods.
pub const WATCHDOG_MIN_MS: f64 = 1.0;
/// Largest peak current (`actuator.peak_current_a`,
/// `backend.can.peak_current_a`), A: twice the rated peak of the bench's
/// coil (LA24-20-000A: 111 N at 11.12 N/A = 9.98 A, thesis §5.1.2), room
/// for another coil of this size, but not for a value no amplifier of
/// this bench delivers (the supervisor clips commands to it, the I²t
/// budget grows with its square).
pub const PEAK_CURRENT_MAX_A: f64 = 20.0;
/// Smallest ratio of `actuator.peak_current_a` to
/// `actuator.continuous_current_a`: 1.25. The I²t budget is
/// `(I_peak² − I_cont²) · t_peak`; at a ratio of 1 it is zero and the
/// protection can never trip (no current above the peak flows, and the
/// accumulator only grows above the continuous rating), so the
/// protection would be configured off. At 1.25 the budget is at least
/// `0.56 · I_cont² · t_peak`. Coils are rated with a peak 3–5 times the
/// continuous current (LA24-20-000A: 4.3).
pub const PEAK_TO_CONTINUOUS_MIN: f64 = 1.25;
/// The X travel of stage 1 on the thesis bench, m: ±1 mm, a factor of
/// two against yielding, with a mechanical stop there (§5.1.2); the
/// probe reads ±1 mm too. `safety.position_limit_m` is below it.
pub const STROKE_M: f64 = 1.0e-3;
/// Smallest `safety.position_limit_m`, m: well above the probe's noise
/// (40 nm RMS, 400 nm peak to peak).
pub const POSITION_LIMIT_MIN_M: f64 = 1.0e-6;
/// Smallest `safety.max_position_step_m`, m: 25 × the probe's RMS noise,
/// so noise alone never trips the jump check.
pub const POSITION_STEP_MIN_M: f64 = 1.0e-6;
/// Fastest plausible motion of stage 1, m/s: within its ±1 mm it cannot
/// exceed about 0.5 m/s (the peak force, 111 N, on the 2.1 kg moving
/// mass across the whole stroke; or a full 1 mm swing at the 80 Hz
/// modes); twice that. `safety.max_position_step_m` is at most this
/// times one loop period (200 µm at 5 kHz).
pub const STAGE_SPEED_MAX_M_PER_S: f64 = 1.0;
/// Longest time the loop may run late or without a sample before the
/// supervisor faults, s: `safety.max_overrun_s`,
/// `safety.max_command_latency_s` and `safety.max_missed_samples` (in
/// ticks: 500 at 5 kHz) are at most this. At the peak force the stage crosses its stroke in
/// well under this, so a larger count protects nothing.
pub const BLIND_MAX_S: f64 = 0.1;
/// Longest time from the last sample to the link fault when every read
/// times out, s: `(safety.max_missed_samples + 1)` × the sample timeout
/// is at most this, as long as the longest device watchdog.
pub const LINK_FAULT_MAX_S: f64 = 1.0;
/// Longest wait for one sample (`[backend.serial]
/// sample_timeout_periods` × period, `[backend.can] sample_timeout_ms`),
/// s. The tests on a loaded 2-core VM need 40 ms; USB bursts are a few
/// ms.
pub const SAMPLE_TIMEOUT_MAX_S: f64 = 0.2;
/// Shortest `[backend.can] sample_timeout_ms`, ms: about one CAN frame
/// at 1 Mbit/s.
pub const CAN_SAMPLE_TIMEOUT_MIN_MS: f64 = 0.1;
/// `[backend.serial] handshake_timeout_ms` range, ms: long enough for a
/// USB device to answer, short enough that a silent device cannot hold
/// the disable (which waits for its acknowledgement) for more than
/// 10 s.
pub const HANDSHAKE_TIMEOUT_MS: (f64, f64) = (1.0, 10_000.0);
/// `safety.i2t_peak_duration_s` range, s: a coil's peak rating holds for
/// seconds (the shipped 1 s), not minutes; below 10 ms the budget is
/// spent in a few ticks.
pub const I2T_PEAK_DURATION_S: (f64, f64) = (0.01, 10.0);
/// `safety.min_phase_margin_deg` range, degrees: `[20, 90)`. Below 20°
/// a loop rings badly and a small plant change destabilises it; 90° and
/// above no useful loop reaches.
pub const MIN_PHASE_MARGIN_DEG: (f64, f64) = (20.0, 90.0);
/// Largest `safety.max_sensitivity_peak` (‖S‖∞): 6 (15.6 dB), a modulus
/// margin of 0.17. It must be above 1, which no loop beats.
pub const MAX_SENSITIVITY_PEAK: f64 = 6.0;
/// Largest `[emulator] position_lsb_m`, m: 1 µm, the smallest jump the
/// supervisor looks for. The smallest is `probe.range_m / (2³¹ − 1)`.
pub const POSITION_LSB_MAX_M: f64 = 1.0e-6;

/// The bounds of the other numeric keys: what a flexure stage on a lab
/// bench, its amplifier, probe and jobs can be, with room around the
/// thesis' benches (the model's own ranges are in
/// [`bench_plant::model::ranges`]). The README's configuration reference and
/// the comments in `bench-config/*.toml` give the same ranges.
pub mod ranges {
    /// `loop.rate_hz`, Hz.
    pub const RATE_HZ: (f64, f64) = (100.0, 100_000.0);
    /// `loop.timing_interval_s`, s.
    pub const TIMING_INTERVAL_S: (f64, f64) = (0.01, 60.0);
    /// `loop.cpu` is below this (the kernel's `CPU_SETSIZE`) and below the
    /// number of CPUs online.
    pub const CPU_SETSIZE: usize = 1024;
    /// `actuator.force_constant_n_per_a`, N/A: voice coils are 1–100 N/A.
    pub const FORCE_CONSTANT_N_PER_A: (f64, f64) = (0.01, 1000.0);
    /// `actuator.bandwidth_hz`, Hz: current loops of linear amplifiers.
    pub const AMPLIFIER_BANDWIDTH_HZ: (f64, f64) = (10.0, 100_000.0);
    /// `probe.range_m` and `stage.mechanical_stop_m`, m: 10 µm to 10 mm.
    pub const TRAVEL_M: (f64, f64) = (1e-5, 1e-2);
    /// `probe.noise_rms_m` and `probe.quantization_m`, m: 0 to 1 µm (the
    /// smallest jump the supervisor looks for), and below `probe.range_m`.
    pub const PROBE_RESOLUTION_M: (f64, f64) = (0.0, 1e-6);
    /// `[backend.serial] baud`, Bd.
    pub const BAUD: (u32, u32) = (50, 20_000_000);
    /// Lowest chirp frequency (`chirp.f_start_hz`, the profile's
    /// breakpoints), Hz; the highest is below Nyquist.
    pub const CHIRP_F_MIN_HZ: f64 = 0.01;
    /// Smallest `chirp.amplitude_a`, A (0.1 mA); the largest is
    /// `actuator.peak_current_a`.
    pub const CHIRP_AMPLITUDE_MIN_A: f64 = 1e-4;
    /// Scale of an `chirp.amplitude_profile` breakpoint.
    pub const PROFILE_SCALE: (f64, f64) = (1e-3, 1.0);
    /// `chirp.duration_s`, s: 0.1 s to 10 minutes.
    pub const CHIRP_DURATION_S: (f64, f64) = (0.1, 600.0);
    /// `chirp.lead_in_s`, `chirp.tail_s`, s: at most a minute each.
    pub const CHIRP_QUIET_MAX_S: f64 = 60.0;
    /// Longest `multisine.period_s`, s: 10 minutes, as a sweep (the
    /// shortest is `1 / chirp.f_start_hz`, so the lowest line reaches
    /// down to the band's start).
    pub const MULTISINE_PERIOD_MAX_S: f64 = 600.0;
    /// `multisine.periods`: two at least (the noise variance is the
    /// spread over periods), at most 1000.
    pub const MULTISINE_PERIODS: (u32, u32) = (2, 1000);
    /// `multisine.realizations` with random phases: four at least (the
    /// variance over M realizations has 2(M − 1) degrees of freedom, and
    /// a fit weighted by it has a cost of finite variance and a finite
    /// covariance only from 6 on: [`crate::ident::frf::MIN_SIGMA_DOF`]),
    /// at most 1000. With Schroeder phases exactly 1.
    pub const MULTISINE_REALIZATIONS: (u32, u32) = (4, 1000);
    /// `multisine.transient_periods`: 0 to 100 discarded periods.
    pub const MULTISINE_TRANSIENT_PERIODS: (u32, u32) = (0, 100);
    /// `multisine.lines_per_decade`, as `identification.points_per_decade`.
    pub const MULTISINE_LINES_PER_DECADE: (u32, u32) = (10, 10_000);
    /// Fewest excited lines of a multisine: an FRF file needs 10 points
    /// ([`crate::ident::frf::MIN_CSV_POINTS`]).
    pub const MULTISINE_LINES_MIN: usize = 10;
    /// `step.duration_s`, s: at most an hour.
    pub const STEP_DURATION_MAX_S: f64 = 3600.0;
    /// `step.settle_s`, `step.smooth_s`, s: at most a minute each.
    pub const STEP_PHASE_MAX_S: f64 = 60.0;
    /// Smallest `|step.step_m|`, m (1 nm); the largest is below
    /// `safety.position_limit_m`.
    pub const STEP_MIN_M: f64 = 1e-9;
    /// Smallest `step.steady_state_window_s`, s.
    pub const STEADY_STATE_WINDOW_MIN_S: f64 = 1e-3;
    /// Most ticks of one job (a chirp's lead-in + sweep + tail, a step's
    /// duration) at the loop rate: 2²⁵ (1.9 h at 5 kHz, 5.6 min at
    /// 100 kHz), so that the job's record fits in memory.
    pub const JOB_TICKS_MAX: u64 = 1 << 25;
    /// `identification.points_per_decade`, at most; also at most
    /// [`points_per_decade_max`] for the relative resolution.
    pub const POINTS_PER_DECADE: (usize, usize) = (10, 10_000);
    /// Grid points per smoothing window, at most: a handful draw the
    /// smoothed curve (its narrowest feature is the window); ten leave a
    /// margin for the plots, more add post-processing time and file size,
    /// not detail.
    pub const POINTS_PER_WINDOW: f64 = 10.0;

    /// The densest meaningful FRF grid, points per decade, for the
    /// smoothing window's full width `relative_resolution × f`:
    /// [`POINTS_PER_WINDOW`] points per window, `10 ln(10) /
    /// relative_resolution` rounded down (5756 at the default 0.4 %), and
    /// at most [`POINTS_PER_DECADE`]'s 10 000 (from 0.23 % down). A window is also at least
    /// `min_bins` DFT bins wide, so this is never finer than the record's
    /// DFT resolution allows either.
    pub fn points_per_decade_max(relative_resolution: f64) -> usize {
        // Rounded down (a product on the bound by 1e-12 is on it).
        let most = (POINTS_PER_WINDOW * std::f64::consts::LN_10 / relative_resolution
            * (1.0 + 1e-12))
            .floor();
        if most.is_finite() && most < POINTS_PER_DECADE.1 as f64 {
            most as usize
        } else {
            POINTS_PER_DECADE.1
        }
    }
    /// `identification.relative_resolution`.
    pub const RELATIVE_RESOLUTION: (f64, f64) = (1e-4, 0.5);
    /// `identification.min_bins`.
    pub const MIN_BINS: (usize, usize) = (3, 1000);
    /// `identification.lpm_degree`, R: 0 (the FRF and the transient locally
    /// constant) to 6. Beyond a quadratic or cubic the local fit spends
    /// degrees of freedom on detail a window narrow against the modes'
    /// half-power bands does not have, and the monomials grow
    /// ill-conditioned (Pintelon & Schoukens 2012, §7.2, and Pintelon et
    /// al. 2010 work with R = 2).
    pub const LPM_DEGREE: (usize, usize) = (0, 6);
    /// `identification.lpm_half_width_bins`, n, at least: `R + 2`, so that
    /// the local fit keeps `q = 2n + 1 − 2(R + 1) ≥ 3` degrees of freedom
    /// for the noise variance (with q < 3 the estimated variance is too
    /// uncertain to judge anything by: its relative spread is `1/√q`, and
    /// `E[1/σ̂²]` is infinite for q = 1).
    pub const LPM_HALF_WIDTH_OVER_DEGREE_MIN: usize = 2;
    /// `identification.lpm_half_width_bins`, n, at most: 50 (a window of
    /// 101 bins). Wider is not local: on the default 65.5 s record it is
    /// 1.5 Hz, more than the half-power band `2ζf` of every mode of the
    /// shipped benches (0.53–0.65 Hz), so the polynomials would smooth
    /// across the resonances they are meant to follow. (At high frequency
    /// `relative_resolution` widens the window in proportion to f, as the
    /// modes' bands widen.)
    pub const LPM_HALF_WIDTH_MAX: usize = 50;
}
