//! The two Oriental Motor BLV R drives as the controller knows them: their Modbus
//! register addresses ([`reg`]), what must match their configuration ([`settings`]),
//! and the drive link's decisions ([`link`]), which the runtime's drive link task
//! carries out on the line (see `docs/drives.md`).

pub mod link;
pub mod settings;

pub use link::{DriveDemand, DriveLink};
pub use settings::{AccelUnit, DriveSettings, LineSettings, Parity, SettingError};

/// A wheel whose measured motor speed is at most this is standing (r/min). The drives
/// report whole r/min and hover around ±1 while holding zero speed.
pub const AT_REST_RPM: i32 = 2;

/// Drive registers (address = 2 × NET-ID) and the NET-IDs of the share lists.
pub mod reg {
    /// DDO operation type (NET-ID 45); DDO position (46), speed, rates follow.
    pub const DDO_OPERATION_TYPE: u16 = 0x005A;
    /// DDO operating speed, r/min of the motor shaft (NET-ID 47).
    pub const DDO_SPEED: u16 = 0x005E;
    /// DDO trigger: 1 applies the fields (NET-ID 51).
    pub const DDO_TRIGGER: u16 = 0x0066;
    /// Driver input command; bit 0 = S-ON (NET-ID 62).
    pub const DRIVER_INPUT_COMMAND: u16 = 0x007C;
    /// Present alarm, 0 = none (NET-ID 64).
    pub const PRESENT_ALARM: u16 = 0x0080;
    /// Alarm reset: acts on the 0 → 1 change (NET-ID 192).
    pub const ALARM_RESET: u16 = 0x0180;
    /// Share control global ID, number, local ID.
    pub const SHARE_CONTROL: u16 = 0x0980;
    /// Share read data 0..11, then share write data 0..11.
    pub const SHARE_LISTS: u16 = 0x0990;
    /// Modbus communication timeout, ms (alarm 85h).
    pub const COMM_TIMEOUT: u16 = 0x138A;

    /// The alarm a drive raises when no valid frame came for its communication timeout
    /// ([`COMM_TIMEOUT`]): de-excited, brake applied.
    pub const ALARM_COMM_TIMEOUT: u32 = 0x85;

    /// S-ON bit of [`DRIVER_INPUT_COMMAND`].
    pub const S_ON: u32 = 1;

    /// What each member reports per cycle: detected position, detected speed,
    /// present alarm. Nothing more: every item makes the read 8 bytes (0.8 ms at
    /// 115200) longer, and a command may have to wait for the read.
    pub const SHARE_READ_LIST: [u32; 3] = [102, 103, 64];
    /// What each member takes with a command: speed, acceleration, deceleration,
    /// trigger (last, so it applies the others). The operation type (16) is not in
    /// it: every hold writes it before the setup, and it never changes.
    pub const SHARE_WRITE_LIST: [u32; 4] = [47, 48, 49, 51];
    /// Slots per list in the drive.
    pub const SHARE_LIST_SLOTS: usize = 12;
}
