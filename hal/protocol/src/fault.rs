//! The device's latched faults and their wire codes: the serial
//! protocol's `fault` field, the CAN status byte's high nibble, and the
//! EtherCAT virtual drive's error code.
//!
//! Layer rule: may use nothing of the crate.

/// A latched device fault (reported in samples and status messages).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceFault {
    /// No valid command for longer than the watchdog time.
    Watchdog,
    /// A command while disabled or a non-finite command.
    BadCommand,
    /// The amplifier (drive) itself faulted (over-current, over-temperature;
    /// injected in the EtherCAT virtual slave).
    Amplifier,
    /// The position feedback failed (the probe has no valid reading): a
    /// servo drive faults on it (the EtherCAT virtual CiA 402 drive).
    Sensor,
}

impl DeviceFault {
    /// Wire code (serial protocol `fault` field, CAN status byte).
    pub fn code(self) -> u8 {
        match self {
            Self::Watchdog => 1,
            Self::BadCommand => 2,
            Self::Amplifier => 3,
            Self::Sensor => 4,
        }
    }

    /// The fault for a wire code, `None` for 0 or an unknown code.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            1 => Some(Self::Watchdog),
            2 => Some(Self::BadCommand),
            3 => Some(Self::Amplifier),
            4 => Some(Self::Sensor),
            _ => None,
        }
    }

    /// Snake-case name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Watchdog => "watchdog",
            Self::BadCommand => "bad_command",
            Self::Amplifier => "amplifier",
            Self::Sensor => "sensor",
        }
    }
}
