//! can: the SocketCAN host backend ([`CanStage`]) and what it shares with
//! the CAN device emulator (`bench_devices::emulator::can`): the
//! `[backend.can]` table and the validation of its frame map
//! (`config.rs`; the map's layout is [`bench_protocol::can`]), the socket
//! primitives ([`socket`]) and [`CanError`] (`error.rs`); the stage itself
//! is in `stage.rs`. Everything public is re-exported here.
//!
//! The device is a CANopen-style node: no handshake, three frames, each laid
//! out by a configurable **frame map** (`[backend.can]`, [`CanConfig`]).
//!
//! # Default frame map (node `n`, default 1)
//!
//! All fields little-endian; byte ranges are half-open.
//!
//! | frame | id | bytes | width | type | scale | unit | key |
//! |---|---|---|---|---|---|---|---|
//! | SYNC (host → device) | `0x080` | — (DLC 0) | | | | | `sync_id` |
//! | command, RPDO1 (host → device) | `0x200 + n` | 0..4 | 32 | `i32` | 1e-6 | A | `command.current` |
//! | | | 4..6 | 16 | `u16` | 1 | sample seq (low bits) | `command.answers_seq` |
//! | | | 6..7 | 8 | `u8` | bit 0: enable | | `command.control` |
//! | sample, TPDO1 (device → host) | `0x180 + n` | 0..4 | 32 | `i32` | 1e-10 | m | `sample.position` |
//! | | | 4..6 | 16 | `u16` | 1 | sample counter | `sample.seq` |
//! | | | 6..7 | 8 | `u8` | status bits | | `sample.status` |
//! | | | — | | (optional) | | A | `sample.measured_current` |
//!
//! Frames are sent with the smallest DLC that holds every mapped field (7 for
//! the defaults); a received frame shorter than that is refused
//! ([`CanError::ShortFrame`], kind `Protocol`).
//!
//! * **Status byte**: bit 0 probe out of range, bit 1 amplifier enabled,
//!   bit 2 amplifier fault, bits 4–7 the latched fault code
//!   ([`DeviceFault::code`](bench_protocol::DeviceFault::code): 1 watchdog, 2 bad command).
//! * **Control byte**: bit 0 enable request. The device **enables on the
//!   rising edge** of the bit (with 0 A, clearing a latched fault) and
//!   disables whenever it reads 0; a latched fault therefore survives
//!   commands that keep the bit set, and only a fresh 0 → 1 edge
//!   ([`Stage::enable`](crate::Stage::enable)) clears it, as with a CANopen fault reset.
//! * **Scaled fields** (`current`, `position`, `measured_current`):
//!   `raw = round(value / scale)`. Encoding **saturates** at the field's
//!   range: signed fields at `±(2^(w−1) − 1)`, unsigned at `[0, 2^w − 1]`.
//!   The most negative code of a signed field, `−2^(w−1)`, is reserved for
//!   "no value": NaN encodes to it and it decodes to NaN (an unsigned field
//!   encodes NaN as 0). So a 1e-6 A/LSB `i32` carries ±2147 A and a
//!   1e-10 m/LSB `i32` carries ±0.21 m.
//! * **Integer fields** (`answers_seq`, `seq`, `status`, `control`) must be
//!   unsigned with scale 1; counters wrap modulo `2^w`. The host unwraps the
//!   sample counter into the monotonic [`Sample::seq`](crate::Sample::seq) (consecutive from 0
//!   at the first sample read after [`Stage::configure`](crate::Stage::configure); a jump is a gap,
//!   counted in [`CanStats`]), and maps [`Command::answers_seq`](crate::Command::answers_seq) back to
//!   the device's counter. With a `w`-bit counter, gaps of `2^(w−1)` samples
//!   or more cannot be told from stale frames.
//!
//! A field table given in the config replaces the default one whole:
//! `offset_byte` and `width_bits` (8, 16, 24 or 32) are required, `signed`
//! (false), `scale` (1) and `endian` (`"little"` | `"big"`) are optional.
//! [`CanConfig::validate`] refuses fields beyond the 8 data bytes, fields
//! overlapping within a frame, widths other than 8/16/24/32, zero or
//! non-finite scales, ids beyond 11 bits (29 with `extended = true`),
//! duplicate ids and node ids outside 1..=127, naming the key.
//!
//! # Clock
//!
//! * `sync_producer = true` (default): the host is the SYNC producer. Each
//!   [`Stage::read_sample`](crate::Stage::read_sample) sends one SYNC and waits (bounded) for the
//!   sample it triggers; the device samples **on SYNC**, so the host's
//!   deadlines pace the loop: [`Clock::Host`](crate::Clock::Host).
//! * `sync_producer = false`: the device samples on its own timer at the
//!   configured period and [`Stage::read_sample`](crate::Stage::read_sample) waits for the next sample
//!   frame: [`Clock::Device`](crate::Clock::Device). The device's rate is set on the device
//!   (CANopen has no handshake); the host takes the requested period as the
//!   device's.
//!
//! In both modes `read_sample` first drains what is queued on the socket:
//! with SYNC, queued samples answer earlier SYNCs and are discarded as late;
//! without, the newest queued sample is returned at once (older ones count
//! as gaps), so a slow tick never leaves the loop behind the device.
//! The wait is bounded by `sample_timeout_ms` (default: two periods, at
//! least 1 ms) and ends in [`CanError::Timeout`].
//!
//! # Errors on the bus
//!
//! The host socket accepts every SocketCAN error class (error-frame mask
//! `CAN_ERR_MASK`) and, on a real CAN socket, only the sample id.
//!
//! * A **bus-off** error frame is a link fault: [`CanError::BusOff`], kind
//!   `Link`, latched until the next [`Stage::configure`](crate::Stage::configure).
//! * Any other error frame (protocol violation, CRC, transceiver, missing
//!   ACK, controller overflow/warning/passive, TX timeout) met while waiting
//!   for a sample makes that read fail with [`CanError::ErrorFrame`], kind
//!   `Crc`: a bad sample, which the loop's link supervision counts.
//!   Lost-arbitration, restart, error-counter and "back to error active"
//!   reports are counted only.
//! * Socket I/O errors are kind `Link` (`NotFound` for a missing interface).
//! * A sample reporting an amplifier fault while the host has the amplifier
//!   enabled fails the read with [`CanError::DeviceFault`], kind
//!   `AmplifierFault` (the device's watchdog or command check tripped).
//!
//! Counters are in [`CanStage::stats`]. `read_sample` and `write_command`
//! do not allocate or log; every wait is bounded (`ppoll` with a deadline,
//! non-blocking socket).
//!
//! The device's watchdog and the emulator's link-fault injection are
//! described with the emulator, in `bench_devices::emulator::can`.
//!
//! Layer rule: may use `os`, `param`.

mod config;
mod error;
pub mod socket;
mod stage;

pub use bench_protocol::can::{
    seq_delta, CommandMap, CommandPayload, Endian, FieldSpec, SampleMap, SamplePayload, ShortFrame,
    CAN_DATA_BYTES, CONTROL_ENABLE, DEFAULT_SYNC_ID, RPDO1_BASE, STATUS_AMPLIFIER_ENABLED,
    STATUS_AMPLIFIER_FAULT, STATUS_FAULT_CODE_SHIFT, STATUS_OUT_OF_RANGE, TPDO1_BASE,
};
pub use config::{validate_command_map, validate_field, validate_sample_map, CanConfig};
pub use error::CanError;
pub use socket::open_socket;
pub use socketcan::CanSocket;
pub use stage::{CanStage, CanStats};
