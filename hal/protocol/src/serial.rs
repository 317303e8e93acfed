//! The serial DAQ wire protocol, version [`VERSION`] (byte-level
//! specification for firmware authors in `hal/protocol/PROTOCOL.md`).
//!
//! A frame is one message encoded with [postcard], followed by the
//! CRC-32C (Castagnoli, `crc::CRC_32_ISCSI`) of those bytes in little-endian
//! order, COBS-encoded, and terminated by one `0x00` byte:
//!
//! ```text
//! frame = COBS( postcard(message) ‖ CRC32C(postcard(message)) as u32 LE ) ‖ 0x00
//! ```
//!
//! COBS removes every zero byte from the encoded frame, so `0x00` only ever
//! marks a frame end and a receiver resynchronises at the next zero after any
//! corruption. A frame is accepted only if it COBS-decodes, its CRC matches,
//! and the message decodes to exactly the bytes before the CRC (no trailing
//! bytes). CRC-32C has Hamming distance 6 up to 5243 bits (Koopman), so
//! every 1–5 bit error in the decoded payload and CRC is detected; an error
//! that hits a COBS code byte shifts bytes instead and passes the CRC with
//! probability 2⁻³² at most.
//!
//! Units are fixed by the protocol: currents in A (`f32`), times in µs,
//! periods in ns, positions as signed probe counts with the count size
//! (`position_lsb_m`, m) announced in the device's [`DeviceHello`].
//!
//! Encoding and decoding use fixed buffers and never allocate, so the host
//! runs them on the real-time tick.
//!
//! [postcard]: https://docs.rs/postcard
//!
//! Layer rule: may use nothing of the crate.

use serde::{Deserialize, Serialize};

/// Protocol version spoken by this crate. A device that answers the hello
/// with another version is refused (`ErrorKind::Protocol`).
pub const VERSION: u16 = 1;

/// Largest encoded frame, bytes, delimiter included. Larger input between
/// two delimiters is discarded as one bad frame.
pub const MAX_FRAME: usize = 64;

/// Largest message before CRC and COBS, bytes.
const MAX_MESSAGE: usize = MAX_FRAME - 4 - 2 - 1;

/// CRC-32C (Castagnoli): polynomial 0x1EDC6F41, reflected, init and xorout
/// 0xFFFFFFFF; check value of `"123456789"` is 0xE3069283.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// Sample status bits ([`WireSample::flags`]).
pub mod flags {
    /// The probe is beyond its range.
    pub const OUT_OF_RANGE: u8 = 1 << 0;
    /// The amplifier is enabled.
    pub const AMPLIFIER_ENABLED: u8 = 1 << 1;
    /// The device has a latched fault (see [`super::WireStatus::fault`]).
    pub const FAULT: u8 = 1 << 2;
    /// The command in force over the period that ended at this sample did
    /// not answer the previous sample (late or missing): see
    /// [`SampleFlags::command_late`](crate::SampleFlags::command_late).
    pub const COMMAND_LATE: u8 = 1 << 3;
}

/// Messages from the host to the device.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum HostMessage {
    /// Tag 0. Opens a session; the device answers with
    /// [`DeviceMessage::Hello`]. The device disables its amplifier.
    Hello {
        /// The host's protocol version.
        version: u16,
    },
    /// Tag 1. Enable the amplifier at 0 A and clear a latched fault; the
    /// watchdog starts. Answered with [`DeviceMessage::Status`].
    Enable,
    /// Tag 2. 0 A and amplifier disabled. Answered with
    /// [`DeviceMessage::Status`].
    Disable,
    /// Tag 3. Current demand for the coming sample period; feeds the
    /// watchdog.
    Command {
        /// Low 32 bits of the sequence number of the sample it answers.
        answers_seq: u32,
        /// Current, A.
        current_a: f32,
    },
    /// Tag 4. Asks for a [`DeviceMessage::Status`].
    StatusRequest,
}

/// What the device says about itself in its hello.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeviceHello {
    /// The device's protocol version (the first field, so any version's
    /// hello can be read this far).
    pub version: u16,
    /// Sample period, ns.
    pub period_ns: u32,
    /// Watchdog time, ms.
    pub watchdog_ms: u32,
    /// Amplifier peak current, A.
    pub peak_current_a: f32,
    /// Continuous current rating, A.
    pub continuous_current_a: f32,
    /// Probe half range, m.
    pub probe_range_m: f32,
    /// Size of one probe count, m.
    pub position_lsb_m: f32,
}

/// A probe reading that is not a number is sent as this count
/// ([`WireSample::position`]).
pub const INVALID_POSITION: i32 = i32::MIN;

/// One probe sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireSample {
    /// Sequence number (wraps at 2³²; the host unwraps it).
    pub seq: u32,
    /// Device time of the sample, µs since the hello.
    pub time_us: u64,
    /// Probe reading, counts of `position_lsb_m`.
    pub position: i32,
    /// Measured amplifier current, A; NaN if the device does not measure it.
    pub current_a: f32,
    /// Status bits, see [`flags`].
    pub flags: u8,
}

/// Device status: the answer to enable/disable/status requests, and sent
/// unprompted when a fault latches.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireStatus {
    /// Amplifier enabled.
    pub enabled: bool,
    /// Latched fault: 0 none, 1 watchdog, 2 bad command.
    pub fault: u8,
    /// Frames the device rejected (CRC, decoding) since the hello.
    pub bad_frames: u32,
    /// Commands that arrived after the period they answered.
    pub late_commands: u32,
}

/// Messages from the device to the host.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum DeviceMessage {
    /// Tag 0. Answer to the host's hello.
    Hello(DeviceHello),
    /// Tag 1. A sample, one per period while the session is open.
    Sample(WireSample),
    /// Tag 2. Status.
    Status(WireStatus),
}

/// Why a frame was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// More than [`MAX_FRAME`] bytes without a delimiter.
    #[error("frame longer than {MAX_FRAME} bytes")]
    TooLong,
    /// Not valid COBS.
    #[error("frame is not valid COBS")]
    Cobs,
    /// Shorter than a message tag plus the CRC.
    #[error("frame too short")]
    TooShort,
    /// CRC mismatch.
    #[error("CRC mismatch")]
    Crc,
    /// CRC matched but the bytes are not a message of this version.
    #[error("CRC matched but the message does not decode")]
    Decode,
}

/// Encodes `msg` as one complete frame (delimiter included) into `out`;
/// returns its length.
///
/// # Panics
/// Never for this module's message types (they all fit [`MAX_FRAME`]).
pub fn encode<M: Serialize>(msg: &M, out: &mut [u8; MAX_FRAME]) -> usize {
    let mut raw = [0u8; MAX_MESSAGE + 4];
    let n = postcard::to_slice_crc32(msg, &mut raw, CRC.digest())
        .expect("every protocol message fits MAX_FRAME")
        .len();
    let m = cobs::encode(&raw[..n], &mut out[..MAX_FRAME - 1]);
    out[m] = 0;
    m + 1
}

/// Decodes one frame's bytes (without the `0x00` delimiter), in place.
///
/// # Errors
/// [`FrameError`] saying why it was rejected.
pub fn decode<M: for<'de> Deserialize<'de>>(frame: &mut [u8]) -> Result<M, FrameError> {
    let n = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    if n < 1 + 4 {
        return Err(FrameError::TooShort);
    }
    let (body, crc_bytes) = frame[..n].split_at(n - 4);
    let sent = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
    if CRC.checksum(body) != sent {
        return Err(FrameError::Crc);
    }
    match postcard::take_from_bytes::<M>(body) {
        Ok((m, [])) => Ok(m),
        _ => Err(FrameError::Decode),
    }
}

/// The protocol version in a device hello frame whose body does not decode
/// as this version's [`DeviceMessage`]: tag 0 then the version varint.
/// `None` if the frame is not a CRC-valid hello of any version.
pub fn peek_hello_version(frame: &mut [u8]) -> Option<u16> {
    let n = cobs::decode_in_place(frame).ok()?;
    if n < 2 + 4 {
        return None;
    }
    let (body, crc_bytes) = frame[..n].split_at(n - 4);
    let sent = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
    if CRC.checksum(body) != sent || body[0] != 0 {
        return None;
    }
    postcard::take_from_bytes::<u16>(&body[1..])
        .ok()
        .map(|(v, _)| v)
}

/// Splits a byte stream into frames at `0x00` delimiters, in a fixed
/// buffer. Feed it what the link delivers, a byte at a time.
#[derive(Debug, Clone)]
pub struct FrameReader {
    buf: [u8; MAX_FRAME],
    len: usize,
    overflow: bool,
}

impl Default for FrameReader {
    fn default() -> Self {
        Self::new()
    }
}

/// A frame cut out of the stream by [`FrameReader::push`].
#[derive(Debug)]
pub enum Frame<'a> {
    /// The bytes between two delimiters (not yet decoded).
    Bytes(&'a mut [u8]),
    /// More than [`MAX_FRAME`] bytes arrived without a delimiter.
    TooLong,
}

impl FrameReader {
    /// An empty reader.
    pub fn new() -> Self {
        Self {
            buf: [0; MAX_FRAME],
            len: 0,
            overflow: false,
        }
    }

    /// Takes one byte; returns a frame when `byte` is a delimiter ending a
    /// non-empty frame.
    pub fn push(&mut self, byte: u8) -> Option<Frame<'_>> {
        if byte == 0 {
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overflow) {
                return Some(Frame::TooLong);
            }
            if len == 0 {
                return None;
            }
            return Some(Frame::Bytes(&mut self.buf[..len]));
        }
        if self.len == MAX_FRAME {
            self.overflow = true;
        } else {
            self.buf[self.len] = byte;
            self.len += 1;
        }
        None
    }

    /// Drops a partial frame (after a reconnect).
    pub fn clear(&mut self) {
        self.len = 0;
        self.overflow = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_is_crc32c() {
        // The check value of CRC-32C (Castagnoli), RFC 3720 §B.4.
        assert_eq!(CRC.checksum(b"123456789"), 0xE306_9283);
    }

    #[test]
    fn every_message_round_trips() {
        let msgs = [
            DeviceMessage::Hello(DeviceHello {
                version: u16::MAX,
                period_ns: u32::MAX,
                watchdog_ms: u32::MAX,
                peak_current_a: -f32::MAX,
                continuous_current_a: f32::NAN,
                probe_range_m: 1e-3,
                position_lsb_m: 1e-10,
            }),
            DeviceMessage::Sample(WireSample {
                seq: u32::MAX,
                time_us: u64::MAX,
                position: i32::MIN,
                current_a: f32::NAN,
                flags: 0xFF,
            }),
            DeviceMessage::Status(WireStatus {
                enabled: true,
                fault: 2,
                bad_frames: u32::MAX,
                late_commands: u32::MAX,
            }),
        ];
        for m in msgs {
            let mut out = [0u8; MAX_FRAME];
            let n = encode(&m, &mut out);
            assert!(n <= MAX_FRAME);
            assert_eq!(out[n - 1], 0);
            assert!(!out[..n - 1].contains(&0));
            let mut scratch = out;
            let back: DeviceMessage = decode(&mut scratch[..n - 1]).unwrap();
            // NaN != NaN: compare the encodings.
            let mut again = [0u8; MAX_FRAME];
            assert_eq!(encode(&back, &mut again), n);
            assert_eq!(again, out);
        }
    }

    #[test]
    fn reader_splits_and_resynchronises() {
        let mut out = [0u8; MAX_FRAME];
        let n = encode(&HostMessage::Enable, &mut out);
        let mut stream = vec![0x55u8; 100]; // garbage, too long
        stream.push(0);
        stream.extend_from_slice(&out[..n]);
        let mut r = FrameReader::new();
        let mut seen = Vec::new();
        for b in stream {
            match r.push(b) {
                Some(Frame::TooLong) => seen.push(Err(FrameError::TooLong)),
                Some(Frame::Bytes(f)) => seen.push(decode::<HostMessage>(f)),
                None => {}
            }
        }
        assert_eq!(
            seen,
            vec![Err(FrameError::TooLong), Ok(HostMessage::Enable)]
        );
    }
}
