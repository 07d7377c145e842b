//! A BLE pad: an Xbox Wireless Controller with BLE firmware 5, served by a second
//! trouble-host stack as a peripheral on its own controller in the air. Its GATT
//! server is the pad's (HID service with the real 283-byte Report Map, one input
//! Report with its Report Reference, an output Report, HID Information and Control
//! Point, Device Information with PnP ID 045E:0B13; the HID characteristics need an
//! encrypted link), its security manager pairs Just Works with bonding and answers
//! the robot's encryption with the bond, and it notifies its input report when the
//! robot subscribes and on every change.
//!
//! ```text
//!   test ──inputs, advertise, forget──▶ AirState ──poke──▶ pad task (trouble-host peripheral)
//!                                                           │ H4 over its AirTransport
//!                                                           ▼
//!                                          the pad's LE controller in the air ◀──link──▶ robot
//! ```

use std::future::poll_fn;
use std::task::Poll;

use base_core::gamepad::{Buttons, Dpad, GamepadState};
use bt_hci::controller::ExternalController;
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_time::{Duration, Timer};
use trouble_host::prelude::*;

use super::state::DeviceId;
use super::{Air, PadEvent};

/// The pad's packet pool: heap packets of its own, so that the pads never take from
/// trouble-host's global default pool, which the robot's host uses.
pub struct PadPool;

pub struct PadPacket(Box<[u8; PAD_PACKET_MTU]>);

const PAD_PACKET_MTU: usize = 251;

impl Packet for PadPacket {}

impl AsRef<[u8]> for PadPacket {
    fn as_ref(&self) -> &[u8] {
        &self.0[..]
    }
}

impl AsMut<[u8]> for PadPacket {
    fn as_mut(&mut self) -> &mut [u8] {
        &mut self.0[..]
    }
}

impl PacketPool for PadPool {
    type Packet = PadPacket;
    const MTU: usize = PAD_PACKET_MTU;

    fn allocate() -> Option<PadPacket> {
        Some(PadPacket(Box::new([0; PAD_PACKET_MTU])))
    }

    fn capacity() -> usize {
        16
    }
}

/// The Xbox Wireless Controller's Report Map (BLE firmware 5), as dumped from a pad.
const REPORT_MAP_HEX: &str =
    include_str!("../../../core/tests/data/hid/xbox-wireless-ble-fw5_045E-0B13.hex");

fn report_map() -> Vec<u8> {
    REPORT_MAP_HEX
        .lines()
        .filter(|line| !line.starts_with('#'))
        .flat_map(str::split_whitespace)
        .map(|pair| u8::from_str_radix(pair, 16).expect("the Report Map file is hex"))
        .collect()
}

/// HID Information: HID 1.11, country 0, normally connectable.
const HID_INFORMATION: [u8; 4] = [0x11, 0x01, 0x00, 0x02];
/// Report Reference: input report 1, output report 3.
const INPUT_REFERENCE: [u8; 2] = [1, 1];
const OUTPUT_REFERENCE: [u8; 2] = [3, 2];
/// PnP ID: USB vendor ID source, Microsoft 045E, product 0B13, version 0x0501.
const PNP_ID: [u8; 7] = [0x02, 0x5E, 0x04, 0x13, 0x0B, 0x01, 0x05];
/// Flags, the gamepad appearance, the HID service, the name.
const ADVERTISING_DATA: &[u8] = &[
    0x02, 0x01, 0x06, // flags: LE general discoverable, no BR/EDR
    0x03, 0x19, 0xC4, 0x03, // appearance 0x03C4, gamepad
    0x03, 0x02, 0x12, 0x18, // incomplete list of 16-bit services: HID
    0x0D, 0x09, b'X', b'b', b'o', b'x', b' ', b'W', b'i', b'r', b'e', b'l', b'e', b's',
];
/// The pad advertises every 20 ms while it is looking for its host.
const ADVERTISING_INTERVAL: Duration = Duration::from_millis(20);

const ATTRIBUTES: usize = 32;

/// The input report as the pad sends it (16 bytes, no report ID): LX LY RX RY (u16,
/// 0x8000 centred, Y grows downwards), LT RT (10 bits), the hat (1 up … 8 up-left,
/// 0 centred), 15 buttons, then Share.
pub fn xbox_report(inputs: &GamepadState) -> [u8; 16] {
    let axis = |value: f32, downwards: bool| {
        let value = value.clamp(-1.0, 1.0);
        let value = if downwards { -value } else { value };
        (32768.0 + value * 32767.0).round().clamp(0.0, 65535.0) as u16
    };
    let trigger = |value: f32| (value.clamp(0.0, 1.0) * 1023.0).round() as u16;
    const BITS: [(Buttons, u16); 11] = [
        (Buttons::A, 0),
        (Buttons::B, 1),
        (Buttons::X, 3),
        (Buttons::Y, 4),
        (Buttons::LEFT_BUMPER, 6),
        (Buttons::RIGHT_BUMPER, 7),
        (Buttons::VIEW, 10),
        (Buttons::MENU, 11),
        (Buttons::HOME, 12),
        (Buttons::LEFT_STICK, 13),
        (Buttons::RIGHT_STICK, 14),
    ];
    let buttons = BITS
        .iter()
        .filter(|(button, _)| inputs.buttons.contains(*button))
        .fold(0u16, |bits, (_, bit)| bits | 1 << bit);
    let mut report = [0u8; 16];
    report[0..2].copy_from_slice(&axis(inputs.left_x, false).to_le_bytes());
    report[2..4].copy_from_slice(&axis(inputs.left_y, true).to_le_bytes());
    report[4..6].copy_from_slice(&axis(inputs.right_x, false).to_le_bytes());
    report[6..8].copy_from_slice(&axis(inputs.right_y, true).to_le_bytes());
    report[8..10].copy_from_slice(&trigger(inputs.left_trigger).to_le_bytes());
    report[10..12].copy_from_slice(&trigger(inputs.right_trigger).to_le_bytes());
    report[12] = hat(inputs.dpad);
    report[13..15].copy_from_slice(&buttons.to_le_bytes());
    report[15] = u8::from(inputs.buttons.contains(Buttons::SHARE));
    report
}

fn hat(dpad: Dpad) -> u8 {
    match (dpad.up, dpad.right, dpad.down, dpad.left) {
        (true, false, false, false) => 1,
        (true, true, false, false) => 2,
        (false, true, false, false) => 3,
        (false, true, true, false) => 4,
        (false, false, true, false) => 5,
        (false, false, true, true) => 6,
        (false, false, false, true) => 7,
        (true, false, false, true) => 8,
        _ => 0,
    }
}

/// The pad's host, for ever: advertise while asked to, serve the robot when it
/// connects, pair when the robot asks, notify every change of the inputs.
pub(super) async fn run(air: Air, device: DeviceId, address: [u8; 6]) {
    let controller = ExternalController::<_, 8>::new(air.transport(device));
    let mut resources: HostResources<PadPool, 1, 3, 1, 4> = HostResources::new();
    let stack = trouble_host::new(controller, &mut resources)
        .set_random_address(Address::random(address))
        .set_io_capabilities(IoCapabilities::NoInputNoOutput)
        .build();
    let map = report_map();
    let neutral = xbox_report(&GamepadState::default());
    let mut input_store = [0u8; 16];
    let mut output_store = [0u8; 8];
    let mut control_store = [0u8; 1];
    let encrypted = PermissionLevel::EncryptionRequired;
    let mut table: AttributeTable<'_, NoopRawMutex, ATTRIBUTES> = AttributeTable::new();
    let input = {
        let mut hid = table.add_service(Service::new(Uuid::new_short(0x1812)));
        hid.add_characteristic_ro(Uuid::new_short(0x2A4A), &HID_INFORMATION[..])
            .read_permission(encrypted)
            .build();
        hid.add_characteristic_ro(Uuid::new_short(0x2A4B), &map[..])
            .read_permission(encrypted)
            .build();
        let mut input = hid.add_characteristic(
            Uuid::new_short(0x2A4D),
            [CharacteristicProp::Read, CharacteristicProp::Notify],
            neutral,
            &mut input_store,
        );
        input.add_descriptor_ro(
            Uuid::new_short(0x2908),
            PermissionLevel::Allowed,
            &INPUT_REFERENCE[..],
        );
        let input = input
            .read_permission(encrypted)
            .cccd_permission(encrypted)
            .build();
        let mut output = hid.add_characteristic(
            Uuid::new_short(0x2A4D),
            [
                CharacteristicProp::Read,
                CharacteristicProp::Write,
                CharacteristicProp::WriteWithoutResponse,
            ],
            [0u8; 8],
            &mut output_store,
        );
        output.add_descriptor_ro(
            Uuid::new_short(0x2908),
            PermissionLevel::Allowed,
            &OUTPUT_REFERENCE[..],
        );
        output
            .read_permission(encrypted)
            .write_permission(encrypted)
            .build();
        hid.add_characteristic(
            Uuid::new_short(0x2A4C),
            [CharacteristicProp::WriteWithoutResponse],
            [0u8; 1],
            &mut control_store,
        )
        .write_permission(encrypted)
        .build();
        hid.build();
        input
    };
    {
        let mut information = table.add_service(Service::new(Uuid::new_short(0x180A)));
        information
            .add_characteristic_ro(Uuid::new_short(0x2A50), &PNP_ID[..])
            .build();
        information.build();
    }
    let server = AttributeServer::<NoopRawMutex, PadPool, ATTRIBUTES, 1>::new(table);
    let mut runner = stack.runner();
    let mut peripheral = stack.peripheral();
    let serve = async {
        loop {
            forget_if_asked(&air, device, &stack);
            if !air.ble_wants_advertising(device) {
                air.ble_poked(device).await;
                continue;
            }
            let parameters = AdvertisementParameters {
                interval_min: ADVERTISING_INTERVAL,
                interval_max: ADVERTISING_INTERVAL,
                ..AdvertisementParameters::default()
            };
            let advertisement = Advertisement::ConnectableScannableUndirected {
                adv_data: ADVERTISING_DATA,
                scan_data: &[],
            };
            let Ok(advertiser) = peripheral.advertise(&parameters, advertisement).await else {
                Timer::after_millis(100).await;
                continue;
            };
            let stop = async {
                while air.ble_wants_advertising(device) {
                    air.ble_poked(device).await;
                }
            };
            // Leaving the race drops the advertiser, which stops the advertising.
            if let Either::First(Ok(connection)) = select(advertiser.accept(), stop).await {
                serve_link(&air, device, &stack, connection, &server, &input).await;
            }
        }
    };
    // The runner only ends on a transport error, which the air never makes.
    let _ = select(runner.run(), serve).await;
}

/// Serves one link to the robot until it ends.
async fn serve_link<C: Controller>(
    air: &Air,
    device: DeviceId,
    stack: &Stack<'_, C, PadPool>,
    connection: Connection<'_, PadPool>,
    server: &AttributeServer<'_, NoopRawMutex, PadPool, ATTRIBUTES, 1>,
    input: &Characteristic<[u8; 16]>,
) {
    if connection.set_bondable(true).is_err() {
        return;
    }
    let Ok(gatt) = connection.with_attribute_server(server) else {
        return;
    };
    let mut sent = xbox_report(&GamepadState::default());
    loop {
        match select(gatt.next(), air.ble_poked(device)).await {
            Either::First(GattConnectionEvent::Disconnected { .. }) => return,
            Either::First(GattConnectionEvent::PairingComplete { bond, .. }) => {
                if bond.is_some() {
                    air.record(device, PadEvent::Paired);
                }
            }
            Either::First(GattConnectionEvent::PairingFailed(_)) => {
                air.record(device, PadEvent::PairingFailed)
            }
            Either::First(GattConnectionEvent::Gatt { event }) => {
                let subscribed = match &event {
                    GattEvent::Write(write) => {
                        Some(write.handle()) == input.cccd_handle
                            && write.with_data(|_, data| data.first().is_some_and(|b| b & 1 != 0))
                    }
                    _ => false,
                };
                if let Ok(reply) = event.accept() {
                    reply.send().await;
                }
                if subscribed {
                    air.record(device, PadEvent::Subscribed);
                    // The pad reports its state as soon as the host listens, so the
                    // host starts from what is held (a dead-man seen released).
                    sent = xbox_report(&air.ble_inputs(device));
                    let _ = input.notify(&gatt, &sent, true).await;
                }
            }
            Either::First(GattConnectionEvent::RequestConnectionParams(request)) => {
                let _ = request.accept(None, stack).await;
            }
            Either::First(_) => {}
            Either::Second(()) => {
                forget_if_asked(air, device, stack);
                let report = xbox_report(&air.ble_inputs(device));
                if report != sent {
                    sent = report;
                    // Not subscribed yet: the value is stored and read on request.
                    let _ = input.notify(&gatt, &report, true).await;
                }
            }
        }
    }
}

/// The pad forgets its bonds when the test asks it to (a reset of the pad).
fn forget_if_asked<C: Controller>(air: &Air, device: DeviceId, stack: &Stack<'_, C, PadPool>) {
    if air.take_forget(device) {
        let identities: Vec<Identity> =
            stack.with_bond_information(|bonds| bonds.iter().map(|bond| bond.identity).collect());
        for identity in identities {
            let _ = stack.remove_bond_information(identity);
        }
    }
}

impl Air {
    fn ble_wants_advertising(&self, device: DeviceId) -> bool {
        let mut state = self.state.borrow_mut();
        let on = state.devices[device].powered;
        on && state.devices[device]
            .ble_pad()
            .is_some_and(|pad| pad.wants_advertising)
    }

    fn ble_inputs(&self, device: DeviceId) -> GamepadState {
        self.state.borrow_mut().devices[device]
            .ble_pad()
            .map(|pad| pad.inputs)
            .unwrap_or_default()
    }

    fn take_forget(&self, device: DeviceId) -> bool {
        self.state.borrow_mut().devices[device]
            .ble_pad()
            .is_some_and(|pad| std::mem::take(&mut pad.forget))
    }

    /// Waits until something changed for the pad's host.
    async fn ble_poked(&self, device: DeviceId) {
        poll_fn(|cx| {
            let mut state = self.state.borrow_mut();
            let Some(pad) = state.devices[device].ble_pad() else {
                return Poll::Pending;
            };
            if std::mem::take(&mut pad.poked) {
                return Poll::Ready(());
            }
            pad.waker = Some(cx.waker().clone());
            Poll::Pending
        })
        .await
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use base_core::hid::{GamepadLayout, VidPid};

    #[test]
    fn the_report_decodes_through_the_real_report_map_to_what_the_pad_holds() {
        let mut layout = GamepadLayout::parse(&report_map(), Some(VidPid::new(0x045E, 0x0B13)))
            .expect("the Xbox Report Map parses");
        let held = GamepadState {
            left_y: 1.0,
            right_x: 0.5,
            left_trigger: 1.0,
            buttons: Buttons::RIGHT_BUMPER.with(Buttons::MENU),
            dpad: Dpad {
                down: true,
                ..Dpad::default()
            },
            ..GamepadState::default()
        };
        let state = layout
            .decode(1, &xbox_report(&held))
            .expect("decodes")
            .expect("a gamepad state");
        assert!(
            state
                .buttons
                .contains(Buttons::RIGHT_BUMPER.with(Buttons::MENU))
        );
        assert!(!state.buttons.contains(Buttons::HOME));
        assert!(state.left_y > 0.99, "forward is forward: {}", state.left_y);
        // Half right, less the dead zone the decoder takes off.
        assert!((0.4..0.5).contains(&state.right_x), "{}", state.right_x);
        assert!(state.left_trigger > 0.99);
        assert!(state.dpad.down && !state.dpad.up);
        assert_eq!(report_map().len(), 283);
    }
}
