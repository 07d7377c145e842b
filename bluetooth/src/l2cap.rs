//! L2CAP for BR/EDR in basic mode (Bluetooth Core, Vol 3, Part A): the basic frame
//! header and the signalling commands a HID host needs, as typed values and bytes.
//! Decoding never panics: a short or inconsistent command is a [`SignalError`], an
//! unknown code is reported with its identifier so that it can be answered with a
//! Command Reject.

use heapless::Vec;

/// The signalling channel of an ACL-U link.
pub const SIGNALLING_CID: u16 = 0x0001;
/// The first dynamically allocated channel ID.
pub const FIRST_DYNAMIC_CID: u16 = 0x0040;
/// HID control channel.
pub const PSM_HID_CONTROL: u16 = 0x0011;
/// HID interrupt channel.
pub const PSM_HID_INTERRUPT: u16 = 0x0013;
/// The MTU every BR/EDR L2CAP channel has until configured otherwise.
pub const DEFAULT_MTU: u16 = 672;
/// The smallest MTU a BR/EDR channel may have.
pub const MIN_MTU: u16 = 48;

/// Connection Response results.
pub mod connect_result {
    pub const SUCCESS: u16 = 0x0000;
    pub const PENDING: u16 = 0x0001;
    pub const PSM_NOT_SUPPORTED: u16 = 0x0002;
    pub const SECURITY_BLOCK: u16 = 0x0003;
    pub const NO_RESOURCES: u16 = 0x0004;
}

/// Connection Response status while pending.
pub const STATUS_AUTHENTICATION_PENDING: u16 = 0x0001;

/// Configuration Response results.
pub mod config_result {
    pub const SUCCESS: u16 = 0x0000;
    pub const UNACCEPTABLE_PARAMETERS: u16 = 0x0001;
    pub const REJECTED: u16 = 0x0002;
    pub const UNKNOWN_OPTIONS: u16 = 0x0003;
}

/// Command Reject reasons.
pub mod reject_reason {
    pub const NOT_UNDERSTOOD: u16 = 0x0000;
    pub const INVALID_CID: u16 = 0x0002;
}

/// Information Request types and results.
pub mod info {
    pub const EXTENDED_FEATURES: u16 = 0x0002;
    pub const SUCCESS: u16 = 0x0000;
    pub const NOT_SUPPORTED: u16 = 0x0001;
}

/// The configuration options the host understands; the others are noted so that a
/// request carrying one can be answered as the specification asks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConfigOptions {
    pub mtu: Option<u16>,
    pub flush_timeout: Option<u16>,
    /// The Retransmission and Flow Control option's mode (0 = basic mode).
    pub mode: Option<u8>,
    /// The first option that is neither understood nor a hint.
    pub unknown: Option<u8>,
}

/// One signalling command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Signal {
    CommandReject {
        reason: u16,
    },
    ConnectionRequest {
        psm: u16,
        source_cid: u16,
    },
    ConnectionResponse {
        destination_cid: u16,
        source_cid: u16,
        result: u16,
        status: u16,
    },
    ConfigurationRequest {
        destination_cid: u16,
        continuation: bool,
        options: ConfigOptions,
    },
    ConfigurationResponse {
        source_cid: u16,
        continuation: bool,
        result: u16,
        options: ConfigOptions,
    },
    DisconnectionRequest {
        destination_cid: u16,
        source_cid: u16,
    },
    DisconnectionResponse {
        destination_cid: u16,
        source_cid: u16,
    },
    /// The data of an echo is not kept: the answer carries none, which is allowed.
    EchoRequest,
    EchoResponse,
    InformationRequest {
        info_type: u16,
    },
    InformationResponse {
        info_type: u16,
        result: u16,
        /// The extended feature mask, when that is what was asked and answered.
        features: Option<u32>,
    },
}

/// A signalling command with the identifier that pairs request and response.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Command {
    pub identifier: u8,
    pub signal: Signal,
}

/// Why a signalling command was not decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SignalError {
    /// Shorter than a command header or than its length field.
    Truncated,
    /// The length does not fit the command's fixed fields, or an option overruns it.
    BadLength { code: u8, identifier: u8 },
    /// A code we do not know (or a response-only code we never asked for).
    UnknownCode { code: u8, identifier: u8 },
    /// Identifier 0 is never valid.
    ZeroIdentifier,
}

/// The signalling commands of one C-frame, decoded one by one.
pub struct Commands<'a> {
    bytes: &'a [u8],
}

/// Splits a C-frame payload into its commands. After the first error the rest of the
/// frame is skipped: its boundaries can no longer be trusted.
pub fn commands(payload: &[u8]) -> Commands<'_> {
    Commands { bytes: payload }
}

impl Iterator for Commands<'_> {
    type Item = Result<Command, SignalError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.bytes.is_empty() {
            return None;
        }
        let result = split_command(self.bytes);
        match result {
            Ok((command, rest)) => {
                self.bytes = rest;
                Some(Ok(command))
            }
            Err(error) => {
                self.bytes = &[];
                Some(Err(error))
            }
        }
    }
}

fn split_command(bytes: &[u8]) -> Result<(Command, &[u8]), SignalError> {
    let [code, identifier, len_lsb, len_msb, rest @ ..] = bytes else {
        return Err(SignalError::Truncated);
    };
    let length = usize::from(u16::from_le_bytes([*len_lsb, *len_msb]));
    if rest.len() < length {
        return Err(SignalError::Truncated);
    }
    let (data, rest) = rest.split_at(length);
    let (code, identifier) = (*code, *identifier);
    if identifier == 0 {
        return Err(SignalError::ZeroIdentifier);
    }
    let signal = decode_signal(code, identifier, data)?;
    Ok((Command { identifier, signal }, rest))
}

fn decode_signal(code: u8, identifier: u8, data: &[u8]) -> Result<Signal, SignalError> {
    let bad = SignalError::BadLength { code, identifier };
    let word = |index: usize| -> Result<u16, SignalError> {
        data.get(index..index + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .ok_or(bad)
    };
    let exactly = |len: usize| if data.len() == len { Ok(()) } else { Err(bad) };
    Ok(match code {
        0x01 => {
            // The reason, then up to four bytes of data that we do not need.
            if data.len() > 6 {
                return Err(bad);
            }
            Signal::CommandReject { reason: word(0)? }
        }
        0x02 => {
            exactly(4)?;
            Signal::ConnectionRequest {
                psm: word(0)?,
                source_cid: word(2)?,
            }
        }
        0x03 => {
            exactly(8)?;
            Signal::ConnectionResponse {
                destination_cid: word(0)?,
                source_cid: word(2)?,
                result: word(4)?,
                status: word(6)?,
            }
        }
        0x04 => Signal::ConfigurationRequest {
            destination_cid: word(0)?,
            continuation: word(2)? & 0x0001 != 0,
            options: data.get(4..).and_then(decode_options).ok_or(bad)?,
        },
        0x05 => Signal::ConfigurationResponse {
            source_cid: word(0)?,
            continuation: word(2)? & 0x0001 != 0,
            result: word(4)?,
            options: data.get(6..).and_then(decode_options).ok_or(bad)?,
        },
        0x06 => {
            exactly(4)?;
            Signal::DisconnectionRequest {
                destination_cid: word(0)?,
                source_cid: word(2)?,
            }
        }
        0x07 => {
            exactly(4)?;
            Signal::DisconnectionResponse {
                destination_cid: word(0)?,
                source_cid: word(2)?,
            }
        }
        0x08 => Signal::EchoRequest,
        0x09 => Signal::EchoResponse,
        0x0A => {
            exactly(2)?;
            Signal::InformationRequest {
                info_type: word(0)?,
            }
        }
        0x0B => {
            let info_type = word(0)?;
            let result = word(2)?;
            let features = match (info_type, result, data.get(4..)) {
                (info::EXTENDED_FEATURES, info::SUCCESS, Some(&[a, b, c, d])) => {
                    Some(u32::from_le_bytes([a, b, c, d]))
                }
                (info::EXTENDED_FEATURES, info::SUCCESS, _) => return Err(bad),
                _ => None,
            };
            Signal::InformationResponse {
                info_type,
                result,
                features,
            }
        }
        _ => return Err(SignalError::UnknownCode { code, identifier }),
    })
}

/// The options of a configuration request or response; `None` if one overruns the
/// command or has the wrong length for its type.
fn decode_options(mut bytes: &[u8]) -> Option<ConfigOptions> {
    let mut options = ConfigOptions::default();
    while !bytes.is_empty() {
        let [kind, len, rest @ ..] = bytes else {
            return None;
        };
        let value = rest.get(..usize::from(*len))?;
        bytes = &rest[usize::from(*len)..];
        let word = || match value {
            [a, b] => Some(u16::from_le_bytes([*a, *b])),
            _ => None,
        };
        match kind & 0x7F {
            0x01 => options.mtu = Some(word()?),
            0x02 => options.flush_timeout = Some(word()?),
            // Quality of service: best effort is all a HID link needs; accepted as sent.
            0x03 if value.len() == 22 => {}
            0x04 if value.len() == 9 => options.mode = Some(value[0]),
            _ if kind & 0x80 != 0 => {}
            _ => {
                options.unknown.get_or_insert(*kind);
            }
        }
    }
    Some(options)
}

/// The longest signalling C-frame payload this host sends.
pub const MAX_SIGNAL_LEN: usize = 16;

/// Encodes one command (header and data).
pub fn encode(command: &Command) -> Vec<u8, MAX_SIGNAL_LEN> {
    let mut data: Vec<u8, { MAX_SIGNAL_LEN - 4 }> = Vec::new();
    let mut put = |word: u16| {
        let _ = data.extend_from_slice(&word.to_le_bytes());
    };
    let code = match command.signal {
        Signal::CommandReject { reason } => {
            put(reason);
            0x01
        }
        Signal::ConnectionRequest { psm, source_cid } => {
            put(psm);
            put(source_cid);
            0x02
        }
        Signal::ConnectionResponse {
            destination_cid,
            source_cid,
            result,
            status,
        } => {
            put(destination_cid);
            put(source_cid);
            put(result);
            put(status);
            0x03
        }
        Signal::ConfigurationRequest {
            destination_cid,
            continuation,
            options,
        } => {
            put(destination_cid);
            put(u16::from(continuation));
            encode_mtu(&mut data, options);
            0x04
        }
        Signal::ConfigurationResponse {
            source_cid,
            continuation,
            result,
            options,
        } => {
            put(source_cid);
            put(u16::from(continuation));
            put(result);
            encode_mtu(&mut data, options);
            0x05
        }
        Signal::DisconnectionRequest {
            destination_cid,
            source_cid,
        } => {
            put(destination_cid);
            put(source_cid);
            0x06
        }
        Signal::DisconnectionResponse {
            destination_cid,
            source_cid,
        } => {
            put(destination_cid);
            put(source_cid);
            0x07
        }
        Signal::EchoRequest => 0x08,
        Signal::EchoResponse => 0x09,
        Signal::InformationRequest { info_type } => {
            put(info_type);
            0x0A
        }
        Signal::InformationResponse {
            info_type,
            result,
            features,
        } => {
            put(info_type);
            put(result);
            if let Some(features) = features {
                let _ = data.extend_from_slice(&features.to_le_bytes());
            }
            0x0B
        }
    };
    let mut bytes = Vec::new();
    let _ = bytes.extend_from_slice(&[code, command.identifier]);
    let _ = bytes.extend_from_slice(&(data.len() as u16).to_le_bytes());
    let _ = bytes.extend_from_slice(&data);
    bytes
}

/// The host sends only the MTU option (and, rejecting, the unknown option's type).
fn encode_mtu<const N: usize>(data: &mut Vec<u8, N>, options: ConfigOptions) {
    if let Some(mtu) = options.mtu {
        let _ = data.extend_from_slice(&[0x01, 2]);
        let _ = data.extend_from_slice(&mtu.to_le_bytes());
    }
    if let Some(kind) = options.unknown {
        let _ = data.extend_from_slice(&[kind, 0]);
    }
}

/// A basic L2CAP frame's header: payload length and channel ID.
pub fn frame_header(payload_len: u16, cid: u16) -> [u8; 4] {
    let [l0, l1] = payload_len.to_le_bytes();
    let [c0, c1] = cid.to_le_bytes();
    [l0, l1, c0, c1]
}

/// Splits a complete basic frame into its channel ID and payload; `None` if the
/// length field does not match the bytes.
pub fn split_frame(frame: &[u8]) -> Option<(u16, &[u8])> {
    let [l0, l1, c0, c1, payload @ ..] = frame else {
        return None;
    };
    (usize::from(u16::from_le_bytes([*l0, *l1])) == payload.len())
        .then(|| (u16::from_le_bytes([*c0, *c1]), payload))
}

#[cfg(test)]
mod tests;
