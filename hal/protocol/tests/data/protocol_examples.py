"""Independent reference for the serial protocol examples in hal/protocol/PROTOCOL.md.

Written from the specification only (postcard wire format, CRC-32C, COBS),
without the Rust code: `python3 hal/protocol/tests/data/protocol_examples.py` prints the
frames that `hal/protocol/tests/serial.rs` checks the encoder and decoder against.
"""
import struct


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli), reflected, init/xorout 0xFFFFFFFF, bit by bit."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def cobs(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing (Cheshire & Baker 1999), no delimiter."""
    out, block = bytearray(), bytearray()
    for b in data:
        if b == 0:
            out += bytes([len(block) + 1]) + block
            block = bytearray()
        else:
            block.append(b)
            if len(block) == 254:
                out += bytes([255]) + block
                block = bytearray()
    out += bytes([len(block) + 1]) + block
    return bytes(out)


def varint(n: int) -> bytes:
    """postcard unsigned varint (LEB128)."""
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def zigzag(n: int) -> int:
    return (n << 1) ^ (n >> 31)


def f32(x: float) -> bytes:
    return struct.pack("<f", x)


def frame(payload: bytes) -> bytes:
    return cobs(payload + struct.pack("<I", crc32c(payload))) + b"\x00"


assert crc32c(b"123456789") == 0xE3069283

examples = {
    # HostMessage::Hello { version: 1 }: tag 0, version 1
    "host_hello_v1": varint(0) + varint(1),
    # HostMessage::Enable: tag 1
    "host_enable": varint(1),
    # HostMessage::Command { answers_seq: 5, current_a: 1.5 }: tag 3
    "host_command_5_1p5": varint(3) + varint(5) + f32(1.5),
    # DeviceMessage::Sample { seq: 300, time_us: 60000, position: -12345
    #   (counts), current_a: 0.25, flags: 0b010 (amplifier enabled) }: tag 1
    "device_sample": varint(1) + varint(300) + varint(60000) + varint(zigzag(-12345))
    + f32(0.25) + bytes([0b010]),
    # DeviceMessage::Hello(DeviceHello { version 1, period 200000 ns,
    #   watchdog 50 ms, peak 9.98 A, cont 2.34 A, range 1e-3 m, lsb 1e-10 m }): tag 0
    "device_hello": varint(0) + varint(1) + varint(200000) + varint(50) + f32(9.98)
    + f32(2.34) + f32(1e-3) + f32(1e-10),
    # DeviceMessage::Status { enabled: true, fault: 0, bad_frames: 0, late_commands: 0 }: tag 2
    "device_status_enabled": varint(2) + bytes([1, 0]) + varint(0) + varint(0),
}

for name, payload in examples.items():
    print(f"{name}: payload {payload.hex(' ')} | crc32c {crc32c(payload):08x} | frame {frame(payload).hex(' ')}")
