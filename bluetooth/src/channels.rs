//! The two L2CAP channels of a HID connection, control (PSM 0x11) and interrupt
//! (PSM 0x13), on one encrypted link, and the signalling that opens them.
//!
//! ```text
//!                 pad: Connection Request            our Configuration Request
//!   Closed ──┬── (link not yet encrypted) ─▶ Pending ── encrypted: Success ──┐
//!            ├── (encrypted): Success ───────────────────────────────────────┤
//!            └── we: Connection Request ─▶ Requested ── Success ─────────────┤
//!                                                                            ▼
//!                     both requests accepted (theirs by us, ours by them)  Configuring
//!   Open ◀───────────────────────────────────────────────────────────────────┘
//! ```
//!
//! - A channel that the pad disconnects, refuses or configures with something we
//!   cannot take ends the whole HID connection: the host then drops the link.
//! - Requests for other PSMs are answered "PSM not supported"; a second request for a
//!   channel already in use "no resources".

use heapless::Vec;

use crate::RECEIVE_MTU;
use crate::l2cap::{
    self, Command, ConfigOptions, FIRST_DYNAMIC_CID, MIN_MTU, PSM_HID_CONTROL, PSM_HID_INTERRUPT,
    STATUS_AUTHENTICATION_PENDING, Signal, SignalError, config_result, connect_result, info,
    reject_reason,
};

/// Which HID channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HidChannel {
    Control,
    Interrupt,
}

impl HidChannel {
    fn psm(self) -> u16 {
        match self {
            HidChannel::Control => PSM_HID_CONTROL,
            HidChannel::Interrupt => PSM_HID_INTERRUPT,
        }
    }

    /// Our channel ID for it: fixed, there is one HID connection at a time.
    pub fn local_cid(self) -> u16 {
        match self {
            HidChannel::Control => FIRST_DYNAMIC_CID,
            HidChannel::Interrupt => FIRST_DYNAMIC_CID + 1,
        }
    }

    fn of_psm(psm: u16) -> Option<HidChannel> {
        match psm {
            PSM_HID_CONTROL => Some(HidChannel::Control),
            PSM_HID_INTERRUPT => Some(HidChannel::Interrupt),
            _ => None,
        }
    }

    fn of_local_cid(cid: u16) -> Option<HidChannel> {
        [HidChannel::Control, HidChannel::Interrupt]
            .into_iter()
            .find(|channel| channel.local_cid() == cid)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Channel {
    Closed,
    /// The pad asked before the link was encrypted; it was told "pending".
    Pending {
        remote_cid: u16,
        identifier: u8,
    },
    /// We asked; the pad has not accepted yet.
    Requested {
        identifier: u8,
    },
    Configuring {
        remote_cid: u16,
        /// The pad accepted our configuration request.
        ours_accepted: bool,
        /// We accepted the pad's; its MTU then.
        their_mtu: Option<u16>,
    },
    Open {
        remote_cid: u16,
        remote_mtu: u16,
    },
}

/// Why the HID connection cannot go on: the host drops the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChannelFailure {
    /// The pad refused to open or to configure a channel.
    Refused { channel: HidChannel, result: u16 },
    /// The pad closed a channel.
    Closed(HidChannel),
    /// The pad rejected one of our requests.
    CommandRejected { reason: u16 },
}

/// The signalling commands one step sends (a connect answer and a configuration
/// request for each channel at most).
pub type Signals = Vec<Command, 6>;

/// The HID connection's channels on one link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HidChannels {
    control: Channel,
    interrupt: Channel,
    next_identifier: u8,
}

impl Default for HidChannels {
    fn default() -> Self {
        Self::new()
    }
}

impl HidChannels {
    pub const fn new() -> HidChannels {
        HidChannels {
            control: Channel::Closed,
            interrupt: Channel::Closed,
            next_identifier: 1,
        }
    }

    fn channel(&mut self, which: HidChannel) -> &mut Channel {
        match which {
            HidChannel::Control => &mut self.control,
            HidChannel::Interrupt => &mut self.interrupt,
        }
    }

    /// Identifiers 1 … 255 in turn (0 is invalid).
    fn identifier(&mut self) -> u8 {
        let identifier = self.next_identifier;
        self.next_identifier = self.next_identifier.checked_add(1).unwrap_or(1);
        identifier
    }

    /// Both channels configured both ways.
    pub fn open(&self) -> bool {
        matches!(self.control, Channel::Open { .. })
            && matches!(self.interrupt, Channel::Open { .. })
    }

    /// The pad's channel ID and MTU for an open channel.
    pub fn remote(&self, which: HidChannel) -> Option<(u16, u16)> {
        match self.get(which) {
            Channel::Open {
                remote_cid,
                remote_mtu,
            } => Some((remote_cid, remote_mtu)),
            _ => None,
        }
    }

    /// Which open channel data on our `cid` belongs to.
    pub fn route(&self, cid: u16) -> Option<HidChannel> {
        HidChannel::of_local_cid(cid).filter(|which| self.remote(*which).is_some())
    }

    fn get(&self, which: HidChannel) -> Channel {
        match which {
            HidChannel::Control => self.control,
            HidChannel::Interrupt => self.interrupt,
        }
    }

    /// The link is encrypted: pending requests are accepted, and, if we made the
    /// connection (`we_open`), we open the channels the pad has not opened.
    pub fn encrypted(&mut self, we_open: bool, out: &mut Signals) {
        for which in [HidChannel::Control, HidChannel::Interrupt] {
            match *self.channel(which) {
                Channel::Pending {
                    remote_cid,
                    identifier,
                } => self.accept(which, remote_cid, identifier, out),
                Channel::Closed if we_open => {
                    let identifier = self.identifier();
                    *self.channel(which) = Channel::Requested { identifier };
                    push(
                        out,
                        identifier,
                        Signal::ConnectionRequest {
                            psm: which.psm(),
                            source_cid: which.local_cid(),
                        },
                    );
                }
                _ => {}
            }
        }
    }

    fn accept(&mut self, which: HidChannel, remote_cid: u16, identifier: u8, out: &mut Signals) {
        push(
            out,
            identifier,
            Signal::ConnectionResponse {
                destination_cid: which.local_cid(),
                source_cid: remote_cid,
                result: connect_result::SUCCESS,
                status: 0,
            },
        );
        self.configure(which, remote_cid, out);
    }

    fn configure(&mut self, which: HidChannel, remote_cid: u16, out: &mut Signals) {
        *self.channel(which) = Channel::Configuring {
            remote_cid,
            ours_accepted: false,
            their_mtu: None,
        };
        let identifier = self.identifier();
        push(
            out,
            identifier,
            Signal::ConfigurationRequest {
                destination_cid: remote_cid,
                continuation: false,
                options: ConfigOptions {
                    mtu: Some(RECEIVE_MTU),
                    ..ConfigOptions::default()
                },
            },
        );
    }

    /// One signalling command from the pad. `encrypted` says whether a channel may be
    /// accepted now (otherwise it is answered "pending").
    pub fn signal(
        &mut self,
        command: Result<Command, SignalError>,
        encrypted: bool,
        out: &mut Signals,
    ) -> Result<(), ChannelFailure> {
        let Command { identifier, signal } = match command {
            Ok(command) => command,
            Err(
                SignalError::UnknownCode { identifier, .. }
                | SignalError::BadLength { identifier, .. },
            ) => {
                let reason = reject_reason::NOT_UNDERSTOOD;
                push(out, identifier, Signal::CommandReject { reason });
                return Ok(());
            }
            // Nothing to answer: no trustworthy identifier.
            Err(SignalError::Truncated | SignalError::ZeroIdentifier) => return Ok(()),
        };
        match signal {
            Signal::ConnectionRequest { psm, source_cid } => {
                self.connection_request(identifier, psm, source_cid, encrypted, out);
                Ok(())
            }
            Signal::ConnectionResponse {
                destination_cid,
                source_cid,
                result,
                ..
            } => self.connection_response(identifier, destination_cid, source_cid, result, out),
            Signal::ConfigurationRequest {
                destination_cid,
                continuation,
                options,
            } => {
                self.configuration_request(identifier, destination_cid, continuation, options, out);
                Ok(())
            }
            Signal::ConfigurationResponse {
                source_cid, result, ..
            } => self.configuration_response(source_cid, result),
            Signal::DisconnectionRequest {
                destination_cid,
                source_cid,
            } => {
                push(
                    out,
                    identifier,
                    Signal::DisconnectionResponse {
                        destination_cid,
                        source_cid,
                    },
                );
                match HidChannel::of_local_cid(destination_cid) {
                    Some(which) if *self.channel(which) != Channel::Closed => {
                        *self.channel(which) = Channel::Closed;
                        Err(ChannelFailure::Closed(which))
                    }
                    _ => Ok(()),
                }
            }
            Signal::EchoRequest => {
                push(out, identifier, Signal::EchoResponse);
                Ok(())
            }
            Signal::InformationRequest { info_type } => {
                let (result, features) = if info_type == info::EXTENDED_FEATURES {
                    // Basic mode only: no extended features.
                    (info::SUCCESS, Some(0))
                } else {
                    (info::NOT_SUPPORTED, None)
                };
                push(
                    out,
                    identifier,
                    Signal::InformationResponse {
                        info_type,
                        result,
                        features,
                    },
                );
                Ok(())
            }
            Signal::CommandReject { reason } => {
                if self.awaits(identifier) {
                    Err(ChannelFailure::CommandRejected { reason })
                } else {
                    Ok(())
                }
            }
            // We never ask for these; the answers change nothing.
            Signal::DisconnectionResponse { .. }
            | Signal::EchoResponse
            | Signal::InformationResponse { .. } => Ok(()),
        }
    }

    /// Whether `identifier` is that of a connection request of ours still unanswered.
    fn awaits(&self, identifier: u8) -> bool {
        [self.control, self.interrupt].contains(&Channel::Requested { identifier })
    }

    fn connection_request(
        &mut self,
        identifier: u8,
        psm: u16,
        remote_cid: u16,
        encrypted: bool,
        out: &mut Signals,
    ) {
        let refuse = |out: &mut Signals, result: u16| {
            push(
                out,
                identifier,
                Signal::ConnectionResponse {
                    destination_cid: 0,
                    source_cid: remote_cid,
                    result,
                    status: 0,
                },
            )
        };
        let Some(which) = HidChannel::of_psm(psm) else {
            return refuse(out, connect_result::PSM_NOT_SUPPORTED);
        };
        if *self.channel(which) != Channel::Closed || remote_cid < FIRST_DYNAMIC_CID {
            return refuse(out, connect_result::NO_RESOURCES);
        }
        if encrypted {
            self.accept(which, remote_cid, identifier, out);
        } else {
            *self.channel(which) = Channel::Pending {
                remote_cid,
                identifier,
            };
            push(
                out,
                identifier,
                Signal::ConnectionResponse {
                    destination_cid: which.local_cid(),
                    source_cid: remote_cid,
                    result: connect_result::PENDING,
                    status: STATUS_AUTHENTICATION_PENDING,
                },
            );
        }
    }

    fn connection_response(
        &mut self,
        identifier: u8,
        remote_cid: u16,
        local_cid: u16,
        result: u16,
        out: &mut Signals,
    ) -> Result<(), ChannelFailure> {
        let Some(which) = HidChannel::of_local_cid(local_cid) else {
            return Ok(());
        };
        if *self.channel(which) != (Channel::Requested { identifier }) {
            return Ok(());
        }
        match result {
            connect_result::SUCCESS => {
                self.configure(which, remote_cid, out);
                Ok(())
            }
            connect_result::PENDING => Ok(()),
            result => {
                *self.channel(which) = Channel::Closed;
                Err(ChannelFailure::Refused {
                    channel: which,
                    result,
                })
            }
        }
    }

    fn configuration_request(
        &mut self,
        identifier: u8,
        local_cid: u16,
        continuation: bool,
        options: ConfigOptions,
        out: &mut Signals,
    ) {
        let channel =
            HidChannel::of_local_cid(local_cid).map(|which| (which, *self.channel(which)));
        let Some((
            which,
            Channel::Configuring {
                remote_cid,
                ours_accepted,
                ..
            },
        )) = channel
        else {
            let reason = reject_reason::INVALID_CID;
            return push(out, identifier, Signal::CommandReject { reason });
        };
        let mtu = options.mtu.unwrap_or(l2cap::DEFAULT_MTU);
        let (result, answer) = if let Some(kind) = options.unknown {
            let unknown = ConfigOptions {
                unknown: Some(kind),
                ..ConfigOptions::default()
            };
            (config_result::UNKNOWN_OPTIONS, unknown)
        } else if continuation || options.mode.is_some_and(|mode| mode != 0) {
            (config_result::REJECTED, ConfigOptions::default())
        } else if mtu < MIN_MTU {
            let minimum = ConfigOptions {
                mtu: Some(MIN_MTU),
                ..ConfigOptions::default()
            };
            (config_result::UNACCEPTABLE_PARAMETERS, minimum)
        } else {
            (config_result::SUCCESS, ConfigOptions::default())
        };
        push(
            out,
            identifier,
            Signal::ConfigurationResponse {
                source_cid: remote_cid,
                continuation: false,
                result,
                options: answer,
            },
        );
        if result == config_result::SUCCESS {
            *self.channel(which) = if ours_accepted {
                Channel::Open {
                    remote_cid,
                    remote_mtu: mtu,
                }
            } else {
                Channel::Configuring {
                    remote_cid,
                    ours_accepted,
                    their_mtu: Some(mtu),
                }
            };
        }
    }

    fn configuration_response(
        &mut self,
        local_cid: u16,
        result: u16,
    ) -> Result<(), ChannelFailure> {
        let Some(which) = HidChannel::of_local_cid(local_cid) else {
            return Ok(());
        };
        let Channel::Configuring {
            remote_cid,
            their_mtu,
            ..
        } = *self.channel(which)
        else {
            return Ok(());
        };
        if result != config_result::SUCCESS {
            *self.channel(which) = Channel::Closed;
            return Err(ChannelFailure::Refused {
                channel: which,
                result,
            });
        }
        *self.channel(which) = match their_mtu {
            Some(remote_mtu) => Channel::Open {
                remote_cid,
                remote_mtu,
            },
            None => Channel::Configuring {
                remote_cid,
                ours_accepted: true,
                their_mtu: None,
            },
        };
        Ok(())
    }
}

fn push(out: &mut Signals, identifier: u8, signal: Signal) {
    // At most one answer and one request per channel per step: it fits.
    let _ = out.push(Command { identifier, signal });
}

#[cfg(test)]
mod tests;
