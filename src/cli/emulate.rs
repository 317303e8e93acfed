//! `bench emulate serial|can|ethercat`: the simulated plant as a DAQ
//! device (or, on EtherCAT, as a CiA 402 drive).

use super::{bad_input, load_config, status};
use bench::jobs::request::parse_fault;
use bench_devices::emulator::serial::{Pty, SerialEmulatorOptions};
use bench_devices::emulator::{DeviceCore, EmulatorStatus, LinkFault, ScheduledLinkFault};
use bench_plant::sim::ScheduledFault;
use clap::{Args, Subcommand};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, Subcommand)]
pub(super) enum EmulateCommand {
    /// Serial DAQ on a new pseudo-terminal: prints its path on the first
    /// line of stdout, then serves `bench ... --backend serial:PATH`.
    Serial(EmulateArgs),
    /// CAN analog I/O module on a SocketCAN interface.
    Can {
        /// CAN interface, e.g. vcan0 (overrides backend.can.interface).
        #[arg(long, value_name = "IFACE")]
        iface: Option<String>,
        #[command(flatten)]
        common: EmulateArgs,
    },
    /// Virtual EtherCAT slave (a CiA 402 drive in CST around the plant, or
    /// the analog profile's terminals; with [[backend.ethercat.slaves]] a
    /// rack of them on one segment) on a network interface (raw socket:
    /// needs CAP_NET_RAW). Faults: drop:FRAMES, wkc:FRAMES, leave_op,
    /// leave_op:POSITION (a rack's terminal), drive_fault, disconnect, at
    /// seconds after the slave first enters OP.
    Ethercat {
        /// Network interface, e.g. a veth end.
        #[arg(value_name = "IFACE")]
        iface: String,
        /// Vendor id to carry in the SII and 0x1018:01 [default:
        /// backend.ethercat.vendor_id] (for testing the identity check).
        #[arg(long, value_name = "ID", value_parser = parse_u32)]
        vendor_id: Option<u32>,
        /// Product code [default: the profile's].
        #[arg(long, value_name = "ID", value_parser = parse_u32)]
        product_id: Option<u32>,
        #[command(flatten)]
        common: EmulateArgs,
    },
}

/// A u32 in decimal or 0x-hex.
fn parse_u32(s: &str) -> Result<u32, String> {
    let r = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(h, 16),
        None => s.parse(),
    };
    r.map_err(|e| format!("{s:?} is not a 32-bit number (decimal or 0x-hex): {e}"))
}

#[derive(Debug, Args)]
#[command(
    mut_arg("config", |a| a.long_help("Bench description (TOML): its plant, rate and [emulator] watchdog apply [default: the built-in Chapter 5 bench; `bench config default` prints it]")),
)]
pub(super) struct EmulateArgs {
    #[command(flatten)]
    config: super::ConfigFlag,
    /// Plant noise seed [default: sim.seed].
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Inject a fault at device time T_S (repeatable): link faults
    /// bitflip:BITS[xFRAMES], drop:FRAMES, delay:S, hold:S (frames held
    /// back once, then sent together), stall:S, disconnect;
    /// plant faults nan, frozen, jump, out_of_range, dead, blind. E.g. stall:0.5@2.
    #[arg(long = "fault", value_name = "KIND@T_S")]
    faults: Vec<String>,
    /// Protocol version to announce (serial; for testing refusal).
    #[arg(long, value_name = "N")]
    protocol_version: Option<u16>,
    /// Current limits to announce in the hello, PEAK,CONTINUOUS in A,
    /// instead of the config's (serial; for testing that the host's limits
    /// win and that values outside the physical ranges, NaN included, are
    /// refused). The device still clips at its config's peak.
    #[arg(long, value_name = "PEAK,CONT", value_parser = parse_currents)]
    announce_currents_a: Option<(f32, f32)>,
    /// Lockstep test mode (serial): while enabled, the device waits for the
    /// answer to each sample before taking the next, so results do not
    /// depend on scheduling.
    #[arg(long)]
    lockstep: bool,
    /// Stop after this long, s (default: until SIGINT/SIGTERM).
    #[arg(long, value_name = "S")]
    duration_s: Option<f64>,
}

/// Parses `PEAK,CONT` (A; any float, NaN and inf included: the host is
/// the one that judges them).
fn parse_currents(s: &str) -> Result<(f32, f32), String> {
    let (p, c) = s
        .split_once(',')
        .ok_or_else(|| format!("{s:?}: expected PEAK,CONTINUOUS in A, e.g. 9.98,2.34"))?;
    let f = |v: &str| {
        v.trim()
            .parse::<f32>()
            .map_err(|e| format!("{v:?} is not a number: {e}"))
    };
    Ok((f(p)?, f(c)?))
}

/// Parses an emulator `--fault KIND@T_S`: a link fault or a plant fault.
pub(super) fn parse_emulator_fault(s: &str) -> Result<EmulatorFault, String> {
    let (kind, at) = s
        .rsplit_once('@')
        .ok_or_else(|| format!("--fault {s}: expected KIND@T_S, e.g. stall:0.5@2"))?;
    let at_s: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| {
            format!("--fault {s}: time {at:?} is not a non-negative number of seconds")
        })?;
    match LinkFault::parse(kind) {
        Ok(kind) => Ok(EmulatorFault::Link(ScheduledLinkFault { at_s, kind })),
        Err(link_err) => match parse_fault(s) {
            Ok(f) => Ok(EmulatorFault::Plant(f)),
            Err(_) => Err(format!(
                "--fault {s}: {link_err}; or a plant fault nan, frozen, drop, jump, out_of_range, dead, blind"
            )),
        },
    }
}

pub(super) enum EmulatorFault {
    Link(ScheduledLinkFault),
    Plant(ScheduledFault),
}

pub(super) fn emulate(cmd: EmulateCommand, stop: Arc<AtomicBool>) -> ExitCode {
    let (args, can_iface) = match cmd {
        EmulateCommand::Serial(a) => (a, None),
        EmulateCommand::Can { iface, common } => (common, Some(iface)),
        EmulateCommand::Ethercat {
            iface,
            vendor_id,
            product_id,
            common,
        } => return emulate_ethercat(&iface, vendor_id, product_id, common, stop),
    };
    let (cfg, config_path) = match load_config(args.config.config.as_deref())
        .and_then(|(c, p)| c.validate(&p).map(|_| (c, p)))
    {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let mut link_faults = Vec::new();
    let mut plant_faults = Vec::new();
    for f in &args.faults {
        match parse_emulator_fault(f) {
            Ok(EmulatorFault::Link(l)) => link_faults.push(l),
            Ok(EmulatorFault::Plant(p)) => plant_faults.push(p),
            Err(e) => return bad_input(e),
        }
    }
    if let Some(d) = args.duration_s {
        if !(d.is_finite() && d > 0.0) {
            return bad_input(format!(
                "--duration-s {d}: must be a positive number of seconds"
            ));
        }
    }
    let seed = args.seed.unwrap_or(cfg.sim.seed);
    let watchdog_ns = (cfg.emulator.watchdog_ms * 1e6) as u64;
    let mut core = match DeviceCore::new(cfg.sim_params(seed), cfg.loop_.period_ns(), watchdog_ns) {
        Ok(c) => c,
        Err(e) => return bad_input(format!("config {}: {e}", config_path.display())),
    };
    for f in plant_faults {
        core.inject(f);
    }
    let priority = (cfg.emulator.priority > 0).then_some(cfg.emulator.priority);
    let status = Arc::new(EmulatorStatus::default());
    let rate_hz = cfg.loop_.rate_hz;
    if let Some(d) = args.duration_s {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(d));
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        });
    }
    let result = match can_iface {
        None => {
            let pty = match Pty::open() {
                Ok(p) => p,
                Err(e) => {
                    errln!("error: cannot create a pseudo-terminal: {e}");
                    return ExitCode::from(status::ERROR);
                }
            };
            outln!("{}", pty.path());
            errln!(
                "serial DAQ emulator on {} at {rate_hz} Hz, watchdog {} ms, protocol v{}; connect with --backend serial:{}; Ctrl-C stops",
                pty.path(),
                cfg.emulator.watchdog_ms,
                args.protocol_version.unwrap_or(bench_protocol::serial::VERSION),
                pty.path()
            );
            let opts = SerialEmulatorOptions {
                protocol_version: args
                    .protocol_version
                    .unwrap_or(bench_protocol::serial::VERSION),
                position_lsb_m: cfg.emulator.position_lsb_m,
                link_faults,
                seed,
                realtime_priority: priority,
                lockstep: args.lockstep,
                announce_currents_a: args.announce_currents_a,
            };
            let st = Arc::clone(&status);
            let s = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("bench-emulator".into())
                .spawn(move || bench_devices::emulator::serial::run(pty, core, &opts, &s, &st))
                .map_err(|e| e.to_string())
                .and_then(|t| t.join().map_err(|_| "emulator thread panicked".to_string()))
                .and_then(|r| r.map_err(|e| e.to_string()))
        }
        Some(iface) => {
            if args.protocol_version.is_some() {
                return bad_input(
                    "--protocol-version: only the serial emulator has a protocol version",
                );
            }
            let ccfg = bench_hal::can::CanConfig {
                interface: iface.unwrap_or_else(|| cfg.backend.can.interface.clone()),
                ..cfg.backend.can.clone()
            };
            let sock = match bench_hal::can::open_socket(&ccfg.interface) {
                Ok(s) => s,
                Err(e) => return bad_input(format!("--iface {}: {e}", ccfg.interface)),
            };
            outln!("{}", ccfg.interface);
            errln!(
                "CAN DAQ emulator on {} node {} at {rate_hz} Hz, watchdog {} ms; connect with --backend socketcan:{}; Ctrl-C stops",
                ccfg.interface, ccfg.node_id, cfg.emulator.watchdog_ms, ccfg.interface
            );
            let st = Arc::clone(&status);
            let s = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("bench-emulator".into())
                .spawn(move || {
                    if let Some(p) = priority {
                        bench_hal::os::make_realtime(p, None);
                    }
                    bench_devices::emulator::can::run_emulator(
                        sock,
                        &ccfg,
                        core,
                        &link_faults,
                        &s,
                        &st,
                    )
                })
                .map_err(|e| e.to_string())
                .and_then(|t| t.join().map_err(|_| "emulator thread panicked".to_string()))
                .and_then(|r| r.map_err(|e| e.to_string()))
        }
    };
    report_stopped(&status);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            errln!("error: emulator: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}

/// The serial or CAN emulator's closing line on stderr: what it sent and
/// took, its timing, and whether its watchdog tripped.
fn report_stopped(status: &EmulatorStatus) {
    use std::sync::atomic::Ordering::Relaxed;
    errln!(
        "emulator stopped: {} samples sent, {} commands, {} bad frames, {} late commands, largest tick lateness {} µs, watchdog {}",
        status.samples_sent.load(Relaxed),
        status.commands_received.load(Relaxed),
        status.bad_frames.load(Relaxed),
        status.late_commands.load(Relaxed),
        status.max_tick_lateness_ns.load(Relaxed) / 1000,
        if status.watchdog_trip_mono_ns.load(Relaxed) != 0 {
            "tripped"
        } else {
            "never tripped"
        }
    );
}

/// `bench emulate ethercat IFACE`.
fn emulate_ethercat(
    iface: &str,
    vendor_id: Option<u32>,
    product_id: Option<u32>,
    args: EmulateArgs,
    stop: Arc<AtomicBool>,
) -> ExitCode {
    use bench_devices::slave::{ScheduledSlaveFault, SlaveFault, SlaveIdentity};
    let (cfg, config_path) = match load_config(args.config.config.as_deref())
        .and_then(|(c, p)| c.validate(&p).map(|_| (c, p)))
    {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    if args.protocol_version.is_some() || args.announce_currents_a.is_some() || args.lockstep {
        return bad_input(
            "--protocol-version, --announce-currents-a, --lockstep: only the serial emulator has them",
        );
    }
    let mut slave_faults = Vec::new();
    let mut plant_faults = Vec::new();
    for f in &args.faults {
        let Some((kind, at)) = f.rsplit_once('@') else {
            return bad_input(format!("--fault {f}: expected KIND@T_S, e.g. drop:3@1.5"));
        };
        let Some(at_s) = at
            .parse::<f64>()
            .ok()
            .filter(|t| t.is_finite() && *t >= 0.0)
        else {
            return bad_input(format!(
                "--fault {f}: time {at:?} is not a non-negative number of seconds"
            ));
        };
        match SlaveFault::parse(kind) {
            Ok(kind) => slave_faults.push(ScheduledSlaveFault { at_s, kind }),
            Err(slave_err) => match parse_fault(f) {
                Ok(p) => plant_faults.push(p),
                Err(_) => {
                    return bad_input(format!(
                        "--fault {f}: {slave_err}; or a plant fault nan, frozen, drop, jump, out_of_range, dead, blind"
                    ))
                }
            },
        }
    }
    if let Some(d) = args.duration_s {
        if !(d.is_finite() && d > 0.0) {
            return bad_input(format!(
                "--duration-s {d}: must be a positive number of seconds"
            ));
        }
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(d));
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        });
    }
    let seed = args.seed.unwrap_or(cfg.sim.seed);
    // The drive's watchdog is the ESC's SM watchdog, set by the master.
    let mut core = match DeviceCore::new(cfg.sim_params(seed), cfg.loop_.period_ns(), u64::MAX / 4)
    {
        Ok(c) => c,
        Err(e) => return bad_input(format!("config {}: {e}", config_path.display())),
    };
    for f in plant_faults {
        core.inject(f);
    }
    let ecfg = cfg.backend.ethercat.clone();
    let id = SlaveIdentity {
        vendor_id: vendor_id.unwrap_or(ecfg.vendor_id),
        product_id: product_id.unwrap_or(ecfg.expected_product_id()),
    };
    let sock = match bench_hal::ethercat::socket::RawSocket::open(iface) {
        Ok(s) => s,
        Err(e) => return bad_input(format!("IFACE {iface}: {e}")),
    };
    let rack = !ecfg.slaves.is_empty();
    if rack && (vendor_id.is_some() || product_id.is_some()) {
        return bad_input(
            "--vendor-id/--product-id: a rack's identities are in [[backend.ethercat.slaves]]",
        );
    }
    outln!("{iface}");
    if rack {
        let names: Vec<String> = ecfg
            .rack_slaves()
            .iter()
            .map(|s| format!("{} 0x{:X}:0x{:08X}", s.label(), s.vendor_id, s.product_id))
            .collect();
        errln!(
            "EtherCAT virtual rack of {} slaves ({}) on {iface}, cycling on each process-data frame; connect with --backend ethercat:PEER; Ctrl-C stops",
            names.len(),
            names.join(", ")
        );
    } else {
        errln!(
            "EtherCAT virtual slave ({} profile, vendor 0x{:08X} product 0x{:08X}) on {iface}, cycling on each process-data frame; connect with --backend ethercat:PEER; Ctrl-C stops",
            ecfg.profile.as_str(),
            id.vendor_id,
            id.product_id
        );
    }
    let priority = (cfg.emulator.priority > 0).then_some(cfg.emulator.priority);
    let status = Arc::new(EmulatorStatus::default());
    let st = Arc::clone(&status);
    let s = Arc::clone(&stop);
    let result = std::thread::Builder::new()
        .name("bench-emulator".into())
        .spawn(move || {
            if let Some(p) = priority {
                bench_hal::os::make_realtime(p, None);
            }
            if rack {
                bench_devices::slave::rack::run_rack(&sock, &ecfg, core, &slave_faults, &s, &st)
            } else {
                bench_devices::slave::run_slave(&sock, &ecfg, core, id, &slave_faults, &s, &st)
            }
        })
        .map_err(|e| e.to_string())
        .and_then(|t| t.join().map_err(|_| "emulator thread panicked".to_string()))
        .and_then(|r| r.map_err(|e| e.to_string()));
    use std::sync::atomic::Ordering::Relaxed;
    errln!(
        "emulator stopped: {} process-data frames, {} output writes, {} bad frames, watchdog {}",
        status.samples_sent.load(Relaxed),
        status.commands_received.load(Relaxed),
        status.bad_frames.load(Relaxed),
        if status.watchdog_trip_mono_ns.load(Relaxed) != 0 {
            "tripped"
        } else {
            "never tripped"
        }
    );
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            errln!("error: emulator: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}
