//! What the tester throws at the robot: timed events, each an input of its own kind or
//! a program that runs for a while (a PC streaming velocity, a firmware update, a
//! flood of reads). A run is a list of them, fixed before it starts, so that the
//! shrinker can drop any of them and the replay runs exactly the same list.
//!
//! The frames are written here from docs/protocol.md, not with the firmware's codec,
//! so the tester cannot share a mistake with it.

use serde::{Deserialize, Serialize};

/// CAN IDs and bytes from docs/protocol.md.
pub mod wire {
    pub const ENABLE: u16 = 0x2E4;
    pub const VELOCITY: u16 = 0x0C8;
    pub const REGISTER_WRITE: u16 = 0x003;
    pub const REGISTER_READ: u16 = 0x004;
    pub const RESET_ODOMETRY: u16 = 0x005;
    pub const HEARTBEAT: u16 = 0x006;
    pub const SCALE_CALIBRATION: u16 = 0x007;
    pub const ODOMETRY_CALIBRATION: u16 = 0x008;
    pub const WEIGHT: u16 = 0x0EA;
    pub const BATTERY: u16 = 0x0EB;
    pub const POSITION: u16 = 0x0EC;
    pub const HEADING: u16 = 0x0ED;
    pub const STATUS: u16 = 0x0EE;
    pub const POSE_TIME: u16 = 0x0EF;
    pub const MEASURED_SPEED: u16 = 0x0F0;
    pub const UPDATE_COMMAND: u16 = 0x2E8;
    pub const UPDATE_REPLY: u16 = 0x2EA;
    pub const UPDATE_DATA: u16 = 0x2EC;

    /// Byte 0 of an enable that refreshes it; anything else withdraws it.
    pub const ENABLE_REFRESH: u8 = 0x40;
    /// Byte 4 of a velocity frame.
    pub const VELOCITY_MARKER: u8 = 0x03;

    pub fn enable(refresh: bool) -> Vec<u8> {
        let mut data = vec![0; 8];
        data[0] = if refresh { ENABLE_REFRESH } else { 0x00 };
        data
    }

    pub fn velocity(linear_mm_s: i16, rotation_mrad_s: i16) -> Vec<u8> {
        let [l0, l1] = linear_mm_s.to_le_bytes();
        let [r0, r1] = rotation_mrad_s.to_le_bytes();
        vec![l0, l1, r0, r1, VELOCITY_MARKER]
    }

    pub fn register_write(address: u8, value: u16) -> Vec<u8> {
        let [high, low] = value.to_be_bytes();
        vec![address, high, low]
    }

    pub fn register_read(address: u8, tag: u16) -> Vec<u8> {
        let [high, low] = tag.to_be_bytes();
        vec![0x01, address, high, low]
    }

    /// The most addresses one bulk read may ask for.
    pub const BULK_READ_MAX: u8 = 8;

    /// A bulk read of `count` addresses from `first` on (1 to 8, not past 255; others
    /// are refused whole).
    pub fn register_bulk_read(first: u8, count: u8, tag: u16) -> Vec<u8> {
        let [high, low] = tag.to_be_bytes();
        vec![0x02, first, count, high, low]
    }
}

/// One of the two pads the controller takes at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PadKind {
    /// A BLE gamepad (the BLE task's).
    Ble,
    /// A PlayStation pad over Bluetooth Classic (the Classic task's).
    Classic,
}

impl PadKind {
    pub const ALL: [PadKind; 2] = [PadKind::Ble, PadKind::Classic];

    pub fn index(self) -> usize {
        match self {
            PadKind::Ble => 0,
            PadKind::Classic => 1,
        }
    }
}

/// What a pad's hands do: the dead-man (RB/R1), the sticks, L2 and the other buttons.
/// Sticks in 1/100 of full scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PadHands {
    pub dead_man: bool,
    pub left_y: i8,
    pub right_x: i8,
    /// LT/L2 pulled (the modifier of the button combinations).
    pub l2: bool,
    /// Other buttons held (bits of the Xbox layout), the D-pad in the top bits.
    pub buttons: u16,
}

/// How a pad takes part. The `air` pads (the Bluetooth radio at the HCI level:
/// spoofed addresses, malformed packets, power off) plug in here as further kinds.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum PadAction {
    /// The pad's task reports its link up (bonded, encrypted).
    Connect,
    /// The link drops (out of range, switched off).
    Drop,
    /// A decoded report.
    Report(PadHands),
    /// The radio guard refused a packet of this pad's link and closed it: the task
    /// reports the link down and the refusal, and reaches for the pad again only after
    /// 1 s.
    PacketRefused,
    /// The BLE host stopped (a transport error, an answer it cannot parse): the task
    /// reports the links down (on the ESP32 the restarted host's HCI Reset reaches the
    /// Classic host too) and starts a fresh host; after the third stop within a minute
    /// it gives the host up until Bluetooth is turned on. Whichever pad names it.
    HostStops,
}

/// A drive fault the virtual drives can play (`crate::drives`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum DriveFault {
    /// Cut from the line (or back on it): hears nothing, keeps its last command.
    Silent { slave: u8, on: bool },
    /// An alarm (e.g. 0x30 overload) on a powered drive.
    Alarm { slave: u8, code: u8 },
    /// Both drives' power.
    Power { on: bool },
    /// One drive browns out and comes back.
    PowerCycle { slave: u8 },
    /// The controller's receive path dies (or heals).
    LoseReplies { on: bool },
    /// One byte of each of the next replies garbled.
    GarbleNext { replies: u8 },
    /// Every reply of one drive garbled (or clean again).
    GarbleOf { slave: u8, on: bool },
    /// Answers exception 06h to everything and executes nothing.
    Busy { slave: u8, on: bool },
    /// Requests longer than this reach the drives garbled (`None` heals the line).
    FailLongerThan { bytes: Option<u8> },
    /// The position counter stands still while the shaft turns (or heals).
    StuckEncoder { slave: u8, on: bool },
    /// The speed register reads this (or heals).
    SpeedReads { slave: u8, rpm: Option<i16> },
    /// The drive's direction parameter at the other value (a replaced drive), or back:
    /// `motion` turns the shaft against its command and reports it so; otherwise the
    /// shaft turns as commanded and its feedback is negated.
    Reversed { slave: u8, motion: bool, on: bool },
}

/// A flash fault in the register store's or the app's flash.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum FlashFault {
    /// The next sector erase takes this long (the datasheets allow up to 400 ms).
    StallNextErase { ms: u16 },
    /// The next writes fail (nothing programmed).
    FailWrites { count: u8 },
    /// The controller's power dies after this many more bytes programmed or erased;
    /// it comes back at once (a power-on).
    PowerCut { after_bytes: u32 },
}

/// How a controller reset comes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ResetKind {
    /// The reset button or a brown-out: treated as a power-on.
    Button,
    /// The firmware panics (the chip's panic handler resets it).
    Panic,
    /// The controller's supply is cut and comes back: RTC RAM forgets too.
    PowerOn,
}

/// How a velocity stream changes its speed from frame to frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SpeedPattern {
    Constant,
    /// A random walk around the start values.
    Wander,
    /// The sign flips every frame.
    Alternating,
}

/// How a velocity stream ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StreamEnd {
    /// The PC just stops sending: the enable lapses.
    Lapse,
    /// The enable is withdrawn (byte 0 ≠ 0x40).
    Withdraw,
    /// A zero velocity, then nothing.
    ZeroVelocity,
}

/// The image an update session sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ImageKind {
    /// A newer image that runs well.
    Healthy,
    /// One that panics at boot (the bootloader must come back to the old one).
    PanicsAtBoot,
    /// One that never hears CONFIRM (its trial must run out).
    NeverConfirms,
    /// One built with drive settings the firmware refuses (the drives' timeout off):
    /// it must never set the drives up.
    RefusedDriveSettings,
    /// An image for another chip (refused before any write).
    OtherChip,
    /// The announced SHA-256 does not match (refused at FINISH).
    WrongDigest,
    /// A newer image nobody signed: the controller trusts the owner's key, so FINISH
    /// must refuse it and it must never boot.
    Unsigned,
    /// Signed, by a key the controller does not trust.
    SignedByStranger,
    /// Signed by the owner, then its signature block's flags changed (a downgrade
    /// claimed).
    Forged,
}

/// What the PC does after the transfer (or instead of finishing it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SessionEnd {
    /// ACTIVATE, then CONFIRM once the new image answers.
    Confirm,
    /// ACTIVATE, then ROLLBACK.
    Rollback,
    /// ACTIVATE, then nothing: the trial must end by itself.
    Walk,
    /// ACTIVATE; then another program, whose session is this one's plus `offset`
    /// (never the same; 0 stands for a tool from before the session byte), sends
    /// CONFIRM (`keep`) or ROLLBACK, which must be refused, and the trial ends by
    /// itself.
    Stranger { offset: u8, keep: bool },
    /// ABORT after this many windows.
    Abort { after_windows: u8 },
    /// Silence after this many windows: the session must time out.
    Vanish { after_windows: u8 },
}

/// One input or program.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Event {
    // --- the robot PC and other programs on CAN ---
    /// A program drives: the enable every `enable_every` frames and a velocity every
    /// `period_ms` for `ms`, then ends as `end` says.
    Stream {
        linear: i16,
        rotation: i16,
        period_ms: u16,
        enable_every: u8,
        ms: u32,
        pattern: SpeedPattern,
        end: StreamEnd,
    },
    /// One frame as given (malformed ones included).
    Frame {
        id: u16,
        data: Vec<u8>,
    },
    /// A register write, then a tagged read-back.
    WriteRegister {
        address: u8,
        value: u16,
    },
    /// Register reads as fast as the bus takes them (`period_us` apart) for `ms`.
    ReadFlood {
        ms: u32,
        period_us: u32,
    },
    /// Update QUERY frames, `period_us` apart, for `ms`.
    QueryFlood {
        ms: u32,
        period_us: u32,
    },
    /// A firmware update session from BEGIN to its end.
    Update {
        session: u8,
        image: ImageKind,
        windows: u8,
        /// Window whose CRC is sent wrong once (it must be sent again).
        bad_crc_window: Option<u8>,
        /// A WINDOW out of turn with this index, sent once after the first window
        /// (a PC tool's bug or a retry gone astray): refused, the session goes on.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stray_window: Option<u16>,
        end: SessionEnd,
    },
    // --- the pads ---
    Pad {
        pad: PadKind,
        action: PadAction,
    },
    // --- the robot's inputs ---
    /// The e-stop pressed (or released).
    Estop {
        pressed: bool,
    },
    /// The e-stop contact chatters for `ms` (pressed `on_us` of every `period_us`),
    /// then rests released.
    EstopChatter {
        period_us: u32,
        on_us: u32,
        ms: u32,
    },
    /// Someone in the safety zone (or gone).
    Zone {
        occupied: bool,
    },
    /// The zone input chatters for `ms`, then rests clear.
    ZoneChatter {
        period_us: u32,
        on_us: u32,
        ms: u32,
    },
    /// The front button held for `ms`.
    Button {
        ms: u32,
    },
    Battery {
        millivolts: u16,
    },
    /// Weight on the scale, g.
    Weight {
        grams: u32,
    },
    /// The load cell stops answering (or answers again).
    LoadCellMissing {
        missing: bool,
    },
    // --- faults ---
    Drive(DriveFault),
    Flash(FlashFault),
    /// The CAN controller goes bus-off (it recovers by itself).
    BusOff,
    /// The CAN controller reports a receive overrun.
    RxOverrun,
    Reset(ResetKind),
}

/// An event and when it starts, ms after the run's start.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Timed {
    pub at_ms: u64,
    pub event: Event,
}

impl Event {
    /// A short name for reports.
    pub fn kind(&self) -> &'static str {
        match self {
            Event::Stream { .. } => "stream",
            Event::Frame { .. } => "frame",
            Event::WriteRegister { .. } => "write-register",
            Event::ReadFlood { .. } => "read-flood",
            Event::QueryFlood { .. } => "query-flood",
            Event::Update { .. } => "update",
            Event::Pad { .. } => "pad",
            Event::Estop { .. } => "estop",
            Event::EstopChatter { .. } => "estop-chatter",
            Event::Zone { .. } => "zone",
            Event::ZoneChatter { .. } => "zone-chatter",
            Event::Button { .. } => "button",
            Event::Battery { .. } => "battery",
            Event::Weight { .. } => "weight",
            Event::LoadCellMissing { .. } => "load-cell",
            Event::Drive(_) => "drive-fault",
            Event::Flash(_) => "flash-fault",
            Event::BusOff => "bus-off",
            Event::RxOverrun => "rx-overrun",
            Event::Reset(_) => "reset",
        }
    }

    /// Whether this event is a fault injected on purpose (for the reports).
    pub fn is_fault(&self) -> bool {
        matches!(
            self,
            Event::Drive(_)
                | Event::Flash(_)
                | Event::BusOff
                | Event::RxOverrun
                | Event::Reset(_)
                | Event::LoadCellMissing { .. }
        )
    }
}

impl std::fmt::Display for Timed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let json = serde_json::to_string(&self.event).map_err(|_| std::fmt::Error)?;
        write!(f, "{:>10.3} s  {json}", self.at_ms as f64 / 1000.0)
    }
}
