//! ethercat: the EtherCAT host backend ([`EthercatStage`], on the
//! `ethercrab` master stack) and what it shares with the virtual slaves it
//! is tested against (`bench_devices::slave`, `bench emulate ethercat
//! IFACE`): the `[backend.ethercat]` table ([`EthercatConfig`]), the wire
//! constants ([`wire`]), the raw socket ([`socket`]) and
//! [`EthercatError`]. Never the other host backends.
//!
//! # The device: a CiA 402 drive in cyclic synchronous torque mode
//!
//! One slave on the segment: a servo drive (CiA 402 = IEC 61800-7-201)
//! driving the voice coil's current, its position actual value the probe.
//! The object dictionary is tabled in `bench_devices::slave::drive`; the process data
//! (`[backend.ethercat] rx_pdo`/`tx_pdo`, written to 0x1600/0x1A00 and
//! assigned by 0x1C12/0x1C13 in PRE-OP) default to
//!
//! | PDO | entry | type | unit |
//! |---|---|---|---|
//! | RxPDO 0x1600 | 0x6040:00 controlword | u16 | |
//! | | 0x2071:00 target current | i32 | µA |
//! | TxPDO 0x1A00 | 0x6041:00 statusword | u16 | |
//! | | 0x6064:00 position actual value | i32 | `position_lsb_m` (1e-10 m) |
//! | | 0x2078:00 current actual value | i32 | µA |
//!
//! 0x6071 target torque (i16, ‰ of the motor rated current 0x6075, read
//! from the drive at bring-up) may replace 0x2071, and 0x6078 (i16, ‰)
//! 0x2078; other entries are passed to the drive and left 0 by the host.
//!
//! # Lifecycle
//!
//! * [`Stage::configure`](crate::Stage::configure): a broadcast read
//!   finds the slave (none: [`EthercatError::NoSlave`]; a rack: see
//!   below); INIT → PRE-OP
//!   (station address, SII identity checked against `vendor_id` /
//!   `product_id`, mailboxes); over CoE the PDO map, 0x6060 = 10 (CST)
//!   and the SM watchdog (0x0400 = 2498: 100 µs steps; 0x0420 =
//!   `watchdog_ms` × 10); ethercrab reads the map back and sets SM2/SM3
//!   and the FMMUs; with `distributed_clocks` SYNC0 at the loop period
//!   (receive-time latch, offsets, 100 static-drift frames at init);
//!   PRE-OP → SAFE-OP (the slave refuses sync-manager sizes that do not
//!   match its map); one exchange. An SDO abort names the config key
//!   ([`EthercatError::Refused`]). Nothing is enabled on any error.
//! * [`Stage::enable`](crate::Stage::enable): SAFE-OP → OP, then the CiA
//!   402 state machine at 0 A: fault reset (if the drive is faulted),
//!   shutdown (0x06), switch on (0x07), enable operation (0x0F), each
//!   awaited in the statusword.
//! * Each tick: [`Stage::write_command`](crate::Stage::write_command) sets
//!   the target and does the tick's one process-data round trip (ethercrab's
//!   `SubDeviceGroup::tx_rx`: one frame with the `LRW` of the image and an
//!   `FPRD` of the AL status), driven on the loop thread by the stage's
//!   own poll loop with a deadline (`exchange_timeout_ms`; by default
//!   the loop's stall bound given by
//!   [`EthercatStage::set_stall_bound_s`], capped by the SM watchdog:
//!   [`EthercatConfig::exchange_timeout_ns`]):
//!   no allocation, no thread hand-off, no timer, no lock (the process
//!   image sits behind [`image_lock::BorrowFlag`], which never waits).
//!   [`Stage::read_sample`](crate::Stage::read_sample) returns the inputs of that round trip (and
//!   exchanges only if none happened since the last read).
//! * [`Stage::disable`](crate::Stage::disable): "disable voltage" with
//!   0 A in one exchange, then back to SAFE-OP.
//!
//! # Errors in the cyclic exchange → HAL kinds → the supervisor
//!
//! | event | error | kind |
//! |---|---|---|
//! | frame not back in time (lost) | [`EthercatError::Timeout`] | `Timeout` |
//! | working counter ≠ the group's sum (ETG.1000.4 §5.4.3.4: +1 per slave whose inputs are read, +2 per slave whose outputs are written; the single device 3 in OP, 1 in SAFE-OP) | [`EthercatError::WorkingCounter`] | `Link` |
//! | a slave not in OP (AL status of each in the same frame) | [`EthercatError::NotOp`] | `Link` |
//! | the distributed clock moved against the host's clock beyond `dc_drift_max_ppm` × 1 s within a second | [`EthercatError::DcDrift`] | `Link` |
//! | statusword fault bit, or the drive left OPERATION ENABLED (analog: the status input's fault bit, or not ready) | [`EthercatError::DriveFault`] | `AmplifierFault` |
//!
//! They come out of `write_command`, which the loop's one supervisor turns
//! into a latched fault and the safe stop (0 A and disable) in the same
//! tick; no rule is kept here.
//!
//! # The analog-terminal profile
//!
//! `profile = "analog"`: DAC 0x7000:01 (i16, ± `dac_full_scale_a`), enable
//! output 0x7010:01 (bit 0), ADC 0x6000:11 (i16, ± `adc_full_scale_m`),
//! status input 0x6020:01 (bit 0 ready, bit 1 fault; optional). `enable`
//! gives the enable output a rising edge and waits for ready.
//!
//! # The analog profile as a rack of terminals
//!
//! `[[backend.ethercat.slaves]]` ([`rack`], [`RackSlave`]): several
//! slaves on the segment (a coupler, an ADC, a DAC, digital output and
//! input terminals), each with its expected identity, its map and the
//! signals it carries. [`Stage::configure`](crate::Stage::configure)
//! brings them all up in one ethercrab group: the count
//! ([`EthercatError::SlaveCount`]) and each identity
//! ([`EthercatError::Identity`], naming `backend.ethercat.slaves[i]` and
//! the position) checked, the map written over CoE to each slave whose SII
//! offers a CoE mailbox (word 0x001C bit 2) and the fixed map of the
//! others taken (each slave's image size checked at SAFE-OP), the SM
//! watchdog written to each slave with outputs. The tick scatters the DAC
//! value and the enable bit into their terminals' outputs and gathers the
//! ADC value and the ready/fault lines at their bit offsets ([`RackLayout`],
//! no allocation, no lock); above that the stage is the single analog
//! device's.
//!
//! # Timing
//!
//! The drive cycles SM-synchronously (see `bench_devices::slave`): the target of tick
//! *k* is applied in the drive's cycle after the frame of tick *k*, and
//! the position that cycle produces comes back in the frame of tick
//! *k* + 1. Against the simulator (which applies the command of tick *k*
//! over the period that ends at sample *k* + 1) the process data add
//! exactly one loop period of delay. The clock is the host's
//! ([`Clock::Host`](crate::Clock::Host)): the loop's deadlines pace the frames.
//!
//! Layer rule: may use `os`, `param`.

pub mod config;
mod error;
pub mod image_lock;
mod master;
pub mod rack;
pub mod socket;
pub mod wire;

pub use config::{EthercatConfig, PdoEntry, Profile, RackSlave};
pub use error::EthercatError;
pub use master::{EthercatStage, EthercatStats};
pub use rack::{RackLayout, SignalAt};
