//! The serial wire protocol against the frames in `hal/protocol/PROTOCOL.md`, computed
//! independently by `hal/protocol/tests/data/protocol_examples.py` (CRC-32C and COBS
//! written from their specifications), and under corruption.

use bench_protocol::serial::{
    decode, encode, DeviceHello, DeviceMessage, Frame, FrameReader, HostMessage, WireSample,
    WireStatus, MAX_FRAME,
};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn encoded<M: serde::Serialize>(m: &M) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let n = encode(m, &mut out);
    out[..n].to_vec()
}

/// (message, frame bytes from protocol_examples.py)
fn host_examples() -> Vec<(HostMessage, &'static str)> {
    vec![
        (HostMessage::Hello { version: 1 }, "01 06 01 d1 f4 0a 03 00"),
        (HostMessage::Enable, "06 01 52 d0 16 a0 00"),
        (
            HostMessage::Command {
                answers_seq: 5,
                current_a: 1.5,
            },
            "03 03 05 01 07 c0 3f 24 2f e6 d1 00",
        ),
    ]
}

fn device_examples() -> Vec<(DeviceMessage, &'static str)> {
    vec![
        (
            DeviceMessage::Sample(WireSample {
                seq: 300,
                time_us: 60_000,
                position: -12_345,
                current_a: 0.25,
                flags: 0b010,
            }),
            "0a 01 ac 02 e0 d4 03 f1 c0 01 01 08 80 3e 02 5b 69 b2 91 00",
        ),
        (
            DeviceMessage::Hello(DeviceHello {
                version: 1,
                period_ns: 200_000,
                watchdog_ms: 50,
                peak_current_a: 9.98,
                continuous_current_a: 2.34,
                probe_range_m: 1e-3,
                position_lsb_m: 1e-10,
            }),
            "01 1a 01 c0 9a 0c 32 14 ae 1f 41 8f c2 15 40 6f 12 83 3a ff e6 db 2e ff 85 90 1c 00",
        ),
        (
            DeviceMessage::Status(WireStatus {
                enabled: true,
                fault: 0,
                bad_frames: 0,
                late_commands: 0,
            }),
            "03 02 01 01 01 05 d5 03 15 e8 00",
        ),
    ]
}

#[test]
fn frames_match_the_independent_reference() {
    for (m, bytes) in host_examples() {
        assert_eq!(encoded(&m), hex(bytes), "{m:?}");
        let mut f = hex(bytes);
        let n = f.len() - 1;
        assert_eq!(decode::<HostMessage>(&mut f[..n]), Ok(m));
    }
    for (m, bytes) in device_examples() {
        assert_eq!(encoded(&m), hex(bytes), "{m:?}");
        let mut f = hex(bytes);
        let n = f.len() - 1;
        assert_eq!(decode::<DeviceMessage>(&mut f[..n]), Ok(m));
    }
}

/// Every frame the reader accepts out of `stream`.
fn accepted(stream: &[u8]) -> Vec<DeviceMessage> {
    let mut r = FrameReader::new();
    let mut out = Vec::new();
    for &b in stream {
        if let Some(Frame::Bytes(f)) = r.push(b) {
            if let Ok(m) = decode::<DeviceMessage>(f) {
                out.push(m);
            }
        }
    }
    out
}

fn random_message(rng: &mut impl Rng) -> DeviceMessage {
    match rng.random_range(0..3) {
        0 => DeviceMessage::Sample(WireSample {
            seq: rng.random(),
            time_us: rng.random::<u64>() >> rng.random_range(0..64),
            position: rng.random(),
            current_a: rng.random_range(-10.0..10.0),
            flags: rng.random_range(0..8),
        }),
        1 => DeviceMessage::Status(WireStatus {
            enabled: rng.random(),
            fault: rng.random_range(0..3),
            bad_frames: rng.random::<u32>() >> rng.random_range(0..32),
            late_commands: rng.random::<u32>() >> rng.random_range(0..32),
        }),
        _ => DeviceMessage::Hello(DeviceHello {
            version: rng.random(),
            period_ns: rng.random(),
            watchdog_ms: rng.random_range(1..1000),
            peak_current_a: rng.random_range(0.0..20.0),
            continuous_current_a: rng.random_range(0.0..20.0),
            probe_range_m: rng.random_range(0.0..1e-2),
            position_lsb_m: rng.random_range(0.0..1e-6),
        }),
    }
}

/// 10⁵ valid frames, each with 1–8 random bits flipped anywhere in the
/// frame (delimiter included): no corrupted frame is ever accepted.
#[test]
fn no_corrupted_frame_is_accepted() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xB17F11B5);
    let mut bits_total = 0u64;
    for _ in 0..100_000 {
        let m = random_message(&mut rng);
        let mut f = encoded(&m);
        // Sanity: the clean frame is accepted.
        assert_eq!(accepted(&f).len(), 1);
        let flips = rng.random_range(1..=8);
        let mut flipped = std::collections::BTreeSet::new();
        while flipped.len() < flips {
            flipped.insert(rng.random_range(0..f.len() * 8));
        }
        for &bit in &flipped {
            f[bit / 8] ^= 1 << (bit % 8);
        }
        bits_total += flips as u64;
        // Terminate, in case the delimiter itself was hit.
        f.push(0);
        let got = accepted(&f);
        assert!(
            got.is_empty(),
            "corrupted frame of {m:?} accepted as {got:?} ({flipped:?})"
        );
    }
    assert!(bits_total >= 100_000);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Random byte streams never panic the reader or decoder, and whatever
    /// they yield re-encodes to a frame that is in the stream (nothing is
    /// made up).
    #[test]
    fn random_streams_never_panic(stream in proptest::collection::vec(any::<u8>(), 0..600)) {
        for m in accepted(&stream) {
            let f = encoded(&m);
            prop_assert!(stream.windows(f.len() - 1).any(|w| w == &f[..f.len() - 1]));
        }
        let mut r = FrameReader::new();
        for &b in &stream {
            if let Some(Frame::Bytes(f)) = r.push(b) {
                let _ = decode::<HostMessage>(f);
            }
        }
    }
}
