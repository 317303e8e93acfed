//! Backend selection: `[backend] kind` in the config, overridden by
//! `--backend sim|serial:PATH|socketcan:IFACE|ethercat:IFACE` on the
//! command line.
//!
//! [`AnyStage`] puts the backends behind one concrete type, so the loop
//! stays monomorphic (no dynamic dispatch or boxing on the tick).

use crate::config::{BackendKind, BenchConfig};
use crate::error::RunError;
use bench_hal::serial::{SerialError, SerialStage};
use bench_hal::{Command, DeviceInfo, ErrorKind, Sample, Stage};
use bench_plant::sim::{ScheduledFault, SimError, SimStage};
use std::fmt;
use std::str::FromStr;

/// A backend named on the command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BackendSpec {
    /// `sim`
    Sim,
    /// `serial:PATH`
    Serial(String),
    /// `socketcan:IFACE`
    Socketcan(String),
    /// `ethercat:IFACE`
    Ethercat(String),
}

impl FromStr for BackendSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, dev) = s.split_once(':').unwrap_or((s, ""));
        match (kind, dev) {
            ("sim", "") => Ok(Self::Sim),
            ("serial", p) if !p.is_empty() => Ok(Self::Serial(p.into())),
            ("socketcan", i) if !i.is_empty() => Ok(Self::Socketcan(i.into())),
            ("ethercat", i) if !i.is_empty() => Ok(Self::Ethercat(i.into())),
            ("serial", _) => Err("serial needs a device path: serial:/dev/ttyACM0".into()),
            ("socketcan", _) => Err("socketcan needs an interface: socketcan:can0".into()),
            ("ethercat", _) => Err("ethercat needs a network interface: ethercat:eth1".into()),
            _ => Err(format!(
                "unknown backend `{s}` (expected sim, serial:PATH, socketcan:IFACE or ethercat:IFACE)"
            )),
        }
    }
}

impl BackendSpec {
    /// The spec in force: the command line's, else the config's.
    pub fn resolve(cli: Option<&BackendSpec>, cfg: &BenchConfig) -> BackendSpec {
        match cli {
            Some(s) => s.clone(),
            None => match cfg.backend.kind {
                BackendKind::Sim => Self::Sim,
                BackendKind::Serial => Self::Serial(cfg.backend.serial.path.clone()),
                BackendKind::Socketcan => Self::Socketcan(cfg.backend.can.interface.clone()),
                BackendKind::Ethercat => Self::Ethercat(cfg.backend.ethercat.interface.clone()),
            },
        }
    }

    /// Whether this is the in-process simulator.
    pub fn is_sim(&self) -> bool {
        matches!(self, Self::Sim)
    }

    /// The pure delay the link adds to the loop, whole loop periods: one
    /// for EtherCAT (the drive cycles SM-synchronously: a target acts in
    /// the cycle after its frame, see `bench_hal::ethercat`), 0 for the
    /// others. The loop check (`check_loop`) puts `z^{−d}` in the loop.
    pub fn process_data_delay_periods(&self) -> u32 {
        match self {
            Self::Ethercat(_) => 1,
            _ => 0,
        }
    }
}

impl fmt::Display for BackendSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Sim => write!(f, "sim"),
            Self::Serial(p) => write!(f, "serial:{p}"),
            Self::Socketcan(i) => write!(f, "socketcan:{i}"),
            Self::Ethercat(i) => write!(f, "ethercat:{i}"),
        }
    }
}

/// Any backend.
#[derive(Debug)]
pub enum AnyStage {
    /// The simulator.
    Sim(Box<SimStage>),
    /// A serial DAQ.
    Serial(Box<SerialStage>),
    /// A SocketCAN module.
    Can(Box<bench_hal::can::CanStage>),
    /// An EtherCAT drive.
    Ethercat(Box<bench_hal::ethercat::EthercatStage>),
}

/// Any backend's error.
#[derive(Debug, thiserror::Error)]
pub enum AnyError {
    /// From the simulator.
    #[error(transparent)]
    Sim(SimError),
    /// From the serial backend.
    #[error(transparent)]
    Serial(SerialError),
    /// From the SocketCAN backend.
    #[error(transparent)]
    Can(bench_hal::can::CanError),
    /// From the EtherCAT backend.
    #[error(transparent)]
    Ethercat(bench_hal::ethercat::EthercatError),
}

impl bench_hal::Error for AnyError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Sim(e) => e.kind(),
            Self::Serial(e) => e.kind(),
            Self::Can(e) => e.kind(),
            Self::Ethercat(e) => e.kind(),
        }
    }
}

macro_rules! each {
    ($self:ident, $s:ident => $e:expr) => {
        match $self {
            AnyStage::Sim($s) => $e.map_err(AnyError::Sim),
            AnyStage::Serial($s) => $e.map_err(AnyError::Serial),
            AnyStage::Can($s) => $e.map_err(AnyError::Can),
            AnyStage::Ethercat($s) => $e.map_err(AnyError::Ethercat),
        }
    };
}

impl Stage for AnyStage {
    type Error = AnyError;

    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, AnyError> {
        each!(self, s => s.configure(period_ns))
    }

    fn enable(&mut self) -> Result<(), AnyError> {
        each!(self, s => s.enable())
    }

    #[inline]
    fn read_sample(&mut self) -> Result<Sample, AnyError> {
        each!(self, s => s.read_sample())
    }

    #[inline]
    fn write_command(&mut self, command: Command) -> Result<(), AnyError> {
        each!(self, s => s.write_command(command))
    }

    fn disable(&mut self) -> Result<(), AnyError> {
        each!(self, s => s.disable())
    }
}

impl AnyStage {
    /// Tells a backend that waits for its link how long the loop's
    /// supervisor tolerates going without a fresh sample, s (infinite:
    /// none); see [`open`]. The others ignore it. Allocates nothing: the
    /// daemon's loop calls it as a job starts and ends.
    pub fn set_stall_bound_s(&mut self, stall_bound_s: f64) {
        if let Self::Ethercat(s) = self {
            s.set_stall_bound_s(stall_bound_s);
        }
    }

    /// Schedules a simulator fault `fault.at_s` seconds from now (tests,
    /// `--inject-fault`).
    ///
    /// # Errors
    /// [`RunError::BadInput`] on hardware.
    pub fn inject(&mut self, fault: ScheduledFault) -> Result<(), RunError> {
        match self {
            Self::Sim(s) => {
                // `at_s` counts from now (a stage that has been running).
                s.inject(ScheduledFault {
                    at_s: fault.at_s + s.device_time_s(),
                    ..fault
                });
                Ok(())
            }
            _ => Err(RunError::option(
                "inject_fault",
                "",
                "only the sim backend injects faults",
            )),
        }
    }

    /// The simulator's noise restarts from `seed` at the next sample
    /// ([`SimStage::reseed`]); hardware has no seed, nothing changes.
    /// Allocates nothing.
    pub fn reseed(&mut self, seed: u64) {
        if let Self::Sim(s) = self {
            s.reseed(seed);
        }
    }

    /// Link counters of a hardware backend since it was opened (`None` for
    /// the simulator). A copy: real-time safe.
    pub fn link_counters(&self) -> Option<LinkCounters> {
        match self {
            Self::Sim(_) => None,
            Self::Serial(s) => Some(LinkCounters::Serial(s.stats())),
            Self::Can(s) => Some(LinkCounters::Can(s.stats())),
            Self::Ethercat(s) => Some(LinkCounters::Ethercat(s.stats())),
        }
    }

    /// Link counters of a hardware backend, as JSON (`None` for the
    /// simulator).
    pub fn link_stats(&self) -> Option<serde_json::Value> {
        self.link_counters().map(LinkCounters::to_json)
    }
}

/// A snapshot of a hardware backend's link counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkCounters {
    /// Serial DAQ.
    Serial(bench_hal::serial::SerialStats),
    /// SocketCAN module.
    Can(bench_hal::can::CanStats),
    /// EtherCAT drive.
    Ethercat(bench_hal::ethercat::EthercatStats),
}

impl LinkCounters {
    /// Fields of the stats that are settings, not counters.
    pub const SETTINGS: &'static [&'static str] = &["exchange_timeout_ns"];

    /// The counters as a JSON object (field names of the backend's stats).
    pub fn to_json(self) -> serde_json::Value {
        match self {
            Self::Serial(s) => serde_json::to_value(s),
            Self::Can(s) => serde_json::to_value(s),
            Self::Ethercat(s) => serde_json::to_value(s),
        }
        .unwrap_or(serde_json::Value::Null)
    }

    /// The counters of what happened between `before` and `after` (one
    /// job on a device that stays open): every counter is the difference;
    /// the `max_*` figures are the largest since the device was opened, and
    /// the settings ([`Self::SETTINGS`]) those in force at `after`.
    pub fn between(before: Self, after: Self) -> serde_json::Value {
        let (b, mut a) = (before.to_json(), after.to_json());
        if let (Some(b), Some(a)) = (b.as_object(), a.as_object_mut()) {
            for (k, v) in a.iter_mut() {
                if k.starts_with("max_") || Self::SETTINGS.contains(&k.as_str()) {
                    continue;
                }
                if let (Some(x), Some(y)) = (v.as_u64(), b.get(k).and_then(|v| v.as_u64())) {
                    *v = serde_json::Value::from(x.saturating_sub(y));
                }
            }
        }
        a
    }
}

/// Opens and configures the backend `spec` at the config's loop rate.
/// `inject` schedules a simulator fault (refused on hardware).
///
/// # Errors
/// [`RunError::BadOption`] naming `backend` (or the config key) and the
/// reason when the device is missing, busy, speaks another protocol
/// version, runs at another rate, announces current limits or a probe range
/// outside the physical ranges
/// ([`crate::rt::supervisor::check_announced`]), or its configuration is
/// invalid. Nothing is enabled.
///
/// `stall_bound_s` is how long the job's supervisor tolerates the loop
/// without a fresh sample (its stall bound, s; infinite: none): a backend
/// that waits for its link bounds the wait by it (EtherCAT's default
/// `exchange_timeout_ms`).
pub fn open(
    spec: &BackendSpec,
    cfg: &BenchConfig,
    config_path: &std::path::Path,
    seed: u64,
    inject: Option<ScheduledFault>,
    stall_bound_s: f64,
) -> Result<(AnyStage, DeviceInfo), RunError> {
    if inject.is_some() && !spec.is_sim() {
        return Err(RunError::option(
            "inject_fault",
            "",
            format!("only the sim backend injects faults (use `bench emulate --fault` for a device), not {spec}"),
        ));
    }
    let (mut stage, info) = open_stage(spec, cfg, config_path, seed, inject, stall_bound_s)?;
    // The device's announcement is checked before anything can be
    // enabled; the loop then runs on the smaller of its limits and the
    // host's (`BenchConfig::current_limits`).
    if let Err(why) = crate::rt::supervisor::check_announced(&info) {
        let _ = stage.disable();
        return Err(RunError::option(
            "backend",
            spec,
            format!("{why}; refused at the handshake, nothing was enabled"),
        ));
    }
    Ok((stage, info))
}

fn open_stage(
    spec: &BackendSpec,
    cfg: &BenchConfig,
    config_path: &std::path::Path,
    seed: u64,
    inject: Option<ScheduledFault>,
    stall_bound_s: f64,
) -> Result<(AnyStage, DeviceInfo), RunError> {
    let period_ns = cfg.loop_.period_ns();
    let bad = |e: &dyn fmt::Display| {
        RunError::option("backend", spec, format!("{e}; nothing was enabled"))
    };
    match spec {
        BackendSpec::Sim => {
            let mut stage = SimStage::new(cfg.sim_params(seed)).map_err(|e| {
                RunError::BadInput(format!("config {}: {e}", config_path.display()))
            })?;
            let info = stage
                .configure(period_ns)
                .map_err(|e| RunError::BadInput(format!("loop.rate_hz: {e}")))?;
            if let Some(f) = inject {
                stage.inject(f);
            }
            Ok((AnyStage::Sim(Box::new(stage)), info))
        }
        BackendSpec::Serial(path) => {
            let scfg = bench_hal::serial::SerialConfig {
                path: path.clone(),
                ..cfg.backend.serial.clone()
            };
            let mut stage = SerialStage::open(&scfg).map_err(|e| bad(&e))?;
            let info = stage.configure(period_ns).map_err(|e| bad(&e))?;
            Ok((AnyStage::Serial(Box::new(stage)), info))
        }
        BackendSpec::Socketcan(iface) => {
            let ccfg = bench_hal::can::CanConfig {
                interface: iface.clone(),
                ..cfg.backend.can.clone()
            };
            let mut stage = bench_hal::can::CanStage::open(&ccfg).map_err(|e| bad(&e))?;
            let info = stage.configure(period_ns).map_err(|e| bad(&e))?;
            Ok((AnyStage::Can(Box::new(stage)), info))
        }
        BackendSpec::Ethercat(iface) => {
            let ecfg = bench_hal::ethercat::EthercatConfig {
                interface: iface.clone(),
                ..cfg.backend.ethercat.clone()
            };
            let mut stage = bench_hal::ethercat::EthercatStage::open(&ecfg).map_err(|e| bad(&e))?;
            // In whole periods, as the supervisor counts it (the daemon's
            // jobs hand theirs over the same way).
            let period_s = period_ns as f64 * 1e-9;
            stage.set_stall_bound_s(
                crate::rt::supervisor::StallBounds::of(stall_bound_s, period_s)
                    .missed_deadlines_s(period_s),
            );
            let info = stage.configure(period_ns).map_err(|e| bad(&e))?;
            Ok((AnyStage::Ethercat(Box::new(stage)), info))
        }
    }
}
