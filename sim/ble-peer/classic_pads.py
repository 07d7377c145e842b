"""Virtual PlayStation pads (DualShock 4, DualSense) over Bluetooth Classic, on Bumble.

Imported by bumble_gamepad.py: the robot's controller there is a ClassicController, so
the robot's Classic host (the firmware's, over the same HCI transport as its BLE host)
meets these pads on the same in-process link as the BLE pads.

Bumble 0.0.236's virtual controller has no Link Key Request (every authentication
pairs again), no Set Connection Encryption (the host waits for ever), no Inquiry, no
page timeout (paging an absent address raises), no Reject Connection Request, and it
does not keep the class of device, the page timeout or a link supervision timeout.
ClassicController adds them, as a real controller behaves, with two simplifications:
the link key check compares the two sides' stored keys instead of running LMP's
challenge and response, and a supervision timeout is played out only when a test
breaks a link (`lose`).

A pad streams its reports on the HID interrupt channel every REPORT_PERIOD_MS (wall
clock), short report 0x01 until the host reads feature report 0x05 (the DualShock 4
also 0x02), then full reports (0x11 DualShock 4, 0x31 DualSense) with their CRC-32.
"""

from __future__ import annotations

import asyncio
import zlib

from bumble import hci, lmp
from bumble.controller import Controller
from bumble.core import PhysicalTransport
from bumble.device import Device, DeviceConfiguration
from bumble.hid import Device as HidDevice
from bumble.host import Host
from bumble.pairing import PairingConfig, PairingDelegate
from bumble.transport.common import AsyncPipeSink

COMMANDS = """\
ps NAME ds4|dualsense ADDRESS  create a PlayStation pad, on, connectable, not bonded
pairing NAME            the pad's pairing mode (Share+PS): discoverable as a gamepad
on NAME [ADDRESS]       the pad is switched on: it pages the host it paired with (or
                        ADDRESS, the robot's being 00:B0:75:00:00:01) and opens its channels
off NAME                the pad switches off: it closes its link
press/release NAME B... buttons: CROSS CIRCLE SQUARE TRIANGLE L1 R1 L2 R2 SHARE OPTIONS
                        L3 R3 PS TOUCHPAD UP DOWN LEFT RIGHT
stick NAME AXIS VALUE   LX LY RX RY, -1.0 .. 1.0 (+LY = forward)
trigger NAME L2|R2 V    0.0 .. 1.0 (also sets the digital L2/R2 bit above 0)
lose NAME               the link breaks: both sides time out after the supervision timeout
silent NAME             the pad stops sending reports; the link stays
talk NAME               the pad sends reports again
short NAME              the pad never leaves the short report (a clone's quirk)
garble NAME             from now on the pad's full reports carry a wrong CRC
battery NAME STATUS     the battery status byte of its full reports, in hex (default 08:
                        85 % on battery; DS4 1A: charging, 100 %)
forget NAME             the pad forgets its link key
state NAME              connected / idle, and the report mode
"""

# The class of device of a gamepad: peripheral (5), gamepad (2), limited discoverable.
GAMEPAD_CLASS = 0x002508
# The robot's controller's public address (stable: a pad's bond names it).
ROBOT_PUBLIC_ADDRESS = "00:B0:75:00:00:01"
REPORT_PERIOD_MS = 4
# The subcode of the ESP32 controller's vendor event for a legacy authentication.
LEGACY_AUTH_SUBCODE = 0x03
DEFAULT_SUPERVISION_SLOTS = 0x7D00  # 20 s, the specification's default
HID_CONTROL_PSM = 0x0011
HID_INTERRUPT_PSM = 0x0013

BUTTONS = {
    # byte, bit (byte 0 is the hat + face buttons, 1 shoulders, 2 PS)
    "SQUARE": (0, 0x10), "CROSS": (0, 0x20), "CIRCLE": (0, 0x40), "TRIANGLE": (0, 0x80),
    "L1": (1, 0x01), "R1": (1, 0x02), "L2": (1, 0x04), "R2": (1, 0x08),
    "SHARE": (1, 0x10), "CREATE": (1, 0x10), "OPTIONS": (1, 0x20),
    "L3": (1, 0x40), "R3": (1, 0x80), "PS": (2, 0x01), "TOUCHPAD": (2, 0x02),
}
# The hat: pressed directions -> value (8 = released).
HAT = {
    frozenset(): 8, frozenset({"UP"}): 0, frozenset({"UP", "RIGHT"}): 1,
    frozenset({"RIGHT"}): 2, frozenset({"DOWN", "RIGHT"}): 3, frozenset({"DOWN"}): 4,
    frozenset({"DOWN", "LEFT"}): 5, frozenset({"LEFT"}): 6, frozenset({"UP", "LEFT"}): 7,
}


def event(*words: object) -> None:
    print("event", *words, flush=True)


def crc32(seed: int, data: bytes) -> bytes:
    return zlib.crc32(bytes([seed]) + data).to_bytes(4, "little")


# -----------------------------------------------------------------------------
# The controller, with the Classic parts Bumble 0.0.236 lacks
# -----------------------------------------------------------------------------
class ClassicController(Controller):
    def __init__(self, name, link, sink=None, public_address=None) -> None:
        super().__init__(name, host_sink=sink, link=link, public_address=public_address)
        self.class_of_device = 0
        self.page_timeout_slots = 0x2000
        self.supervision_slots: dict[int, int] = {}
        # async (address) -> link key or None: the key this side's host holds.
        self.key_source = None
        self.inquiry: asyncio.Task | None = None

    def complete(self, command, status=hci.HCI_ErrorCode.SUCCESS) -> None:
        self._send_hci_command_status(status, command.op_code)

    def peer(self, address):
        found = self.link.find_classic_controller(address)
        return found if isinstance(found, ClassicController) else None

    def on_hci_write_class_of_device_command(self, command):
        self.class_of_device = command.class_of_device
        return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS)

    def on_hci_write_page_timeout_command(self, command):
        self.page_timeout_slots = command.page_timeout
        return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS)

    def on_hci_write_secure_connections_host_support_command(self, _command):
        return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS)

    def on_hci_write_default_link_policy_settings_command(self, _command):
        return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS)

    def on_hci_write_link_supervision_timeout_command(self, command):
        connection = self.find_classic_connection_by_handle(command.handle)
        status = hci.HCI_ErrorCode.SUCCESS
        if connection is None:
            status = hci.HCI_ErrorCode.UNKNOWN_CONNECTION_IDENTIFIER_ERROR
        elif connection.role != hci.Role.CENTRAL:
            status = hci.HCI_ErrorCode.COMMAND_DISALLOWED_ERROR
        else:
            self.supervision_slots[command.handle] = command.link_supervision_timeout
            event("classic-supervision", command.link_supervision_timeout * 625 // 1000)
        return hci.HCI_Write_Link_Supervision_Timeout_ReturnParameters(
            status=status, handle=command.handle
        )

    def supervision_ms(self, handle: int) -> int:
        return self.supervision_slots.get(handle, DEFAULT_SUPERVISION_SLOTS) * 625 // 1000

    # Inquiry: every discoverable controller answers once, until the inquiry ends.
    def on_hci_inquiry_command(self, command):
        if self.inquiry is not None:
            self.complete(command, hci.HCI_ErrorCode.COMMAND_DISALLOWED_ERROR)
            return None
        self.complete(command)
        event("classic-inquiry", "on")
        self.inquiry = asyncio.get_running_loop().create_task(
            self.run_inquiry(command.inquiry_length * 1.28)
        )
        return None

    async def run_inquiry(self, length_s: float) -> None:
        answered = set()
        deadline = asyncio.get_running_loop().time() + length_s
        try:
            while asyncio.get_running_loop().time() < deadline:
                for other in list(self.link.controllers):
                    address = other.public_address
                    discoverable = getattr(other, "classic_scan_enable", 0) & 0x01
                    if other is self or not discoverable or address in answered:
                        continue
                    answered.add(address)
                    self.send_hci_packet(
                        hci.HCI_Inquiry_Result_Event(
                            bd_addr=[address],
                            page_scan_repetition_mode=[1],
                            reserved_0=[0],
                            reserved_1=[0],
                            class_of_device=[getattr(other, "class_of_device", 0)],
                            clock_offset=[0],
                        )
                    )
                await asyncio.sleep(0.05)
            self.send_hci_packet(hci.HCI_Inquiry_Complete_Event(status=0))
        finally:
            self.inquiry = None

    def on_hci_inquiry_cancel_command(self, _command):
        if self.inquiry is not None:
            self.inquiry.cancel()
            self.inquiry = None
            event("classic-inquiry", "off")
        return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS)

    # Paging: an absent controller, or one without page scan, is a page timeout.
    def on_hci_create_connection_command(self, command):
        target = self.peer(command.bd_addr)
        if target is not None and target.classic_scan_enable & 0x02:
            return super().on_hci_create_connection_command(command)
        self.complete(command, hci.HCI_COMMAND_STATUS_PENDING)
        timeout_s = self.page_timeout_slots * 0.000625

        def timed_out() -> None:
            self.send_hci_packet(
                hci.HCI_Connection_Complete_Event(
                    status=hci.HCI_ErrorCode.PAGE_TIMEOUT_ERROR,
                    connection_handle=0,
                    bd_addr=command.bd_addr,
                    link_type=hci.HCI_Connection_Complete_Event.LinkType.ACL,
                    encryption_enabled=0,
                )
            )

        asyncio.get_running_loop().call_later(timeout_s, timed_out)
        return None

    def on_hci_reject_connection_request_command(self, command):
        self.complete(command)
        self.classic_connections.pop(command.bd_addr, None)
        self.send_lmp_packet(
            command.bd_addr,
            lmp.LmpNotAccepted(lmp.Opcode.LMP_HOST_CONNECTION_REQ, command.reason),
        )
        self.send_hci_packet(
            hci.HCI_Connection_Complete_Event(
                status=command.reason,
                connection_handle=0,
                bd_addr=command.bd_addr,
                link_type=hci.HCI_Connection_Complete_Event.LinkType.ACL,
                encryption_enabled=0,
            )
        )
        return None

    # Authentication asks the host for the link key first; pairing only without one.
    def on_hci_authentication_requested_command(self, command):
        connection = self.find_classic_connection_by_handle(command.connection_handle)
        if connection is None:
            self.complete(command, hci.HCI_ErrorCode.UNKNOWN_CONNECTION_IDENTIFIER_ERROR)
            return None
        self.complete(command, hci.HCI_COMMAND_STATUS_PENDING)
        connection.ssp_state.is_initiator = True
        self.send_hci_packet(hci.HCI_Link_Key_Request_Event(bd_addr=connection.peer_address))
        return None

    def on_hci_link_key_request_reply_command(self, command):
        connection = self.classic_connections.get(command.bd_addr)
        if connection is not None:
            asyncio.get_running_loop().create_task(
                self.check_key(connection, bytes(command.link_key))
            )
        return hci.HCI_StatusAndAddressReturnParameters(
            status=hci.HCI_ErrorCode.SUCCESS, bd_addr=command.bd_addr
        )

    async def check_key(self, connection, key: bytes) -> None:
        """Both sides must hold the same key (LMP's challenge and response, simplified)."""
        peer = self.peer(connection.peer_address)
        peer_key = None
        if peer is not None and peer.key_source is not None:
            peer_key = await peer.key_source(self.public_address)
        if peer_key == key:
            connection.ssp_state.link_key = key
            connection.ssp_state.authenticated = True
            status = hci.HCI_ErrorCode.SUCCESS
        else:
            status = hci.HCI_ErrorCode.PIN_OR_KEY_MISSING_ERROR
            event("classic-key-mismatch", connection.peer_address)
        self.send_hci_packet(
            hci.HCI_Authentication_Complete_Event(
                status=status, connection_handle=connection.handle
            )
        )
        if status == hci.HCI_ErrorCode.SUCCESS:
            # The ESP32's controller in dual mode, with its legacy authentication event
            # on, reports an authentication by link key with a vendor event (code 0xFF,
            # subcode, the link's handle): the robot's hosts must take it in their stride.
            handle = connection.handle.to_bytes(2, "little")
            self.send_hci_packet(
                hci.HCI_Event(bytes([LEGACY_AUTH_SUBCODE]) + handle, event_code=0xFF)
            )
            event("vendor-legacy-auth", connection.peer_address)

    def on_hci_set_connection_encryption_command(self, command):
        connection = self.find_classic_connection_by_handle(command.connection_handle)
        if connection is None:
            self.complete(command, hci.HCI_ErrorCode.UNKNOWN_CONNECTION_IDENTIFIER_ERROR)
            return None
        self.complete(command, hci.HCI_COMMAND_STATUS_PENDING)
        authenticated = connection.ssp_state.authenticated
        status = (
            hci.HCI_ErrorCode.SUCCESS
            if authenticated
            else hci.HCI_ErrorCode.INSUFFICIENT_SECURITY_ERROR
        )
        enabled = int(authenticated and bool(command.encryption_enable))
        self.send_hci_packet(
            hci.HCI_Encryption_Change_Event(
                status=status,
                connection_handle=connection.handle,
                encryption_enabled=enabled,
            )
        )
        peer = self.peer(connection.peer_address)
        if peer is not None and authenticated:
            peer.on_peer_encrypted(self.public_address, enabled)
        return None

    def on_peer_encrypted(self, address, enabled: int) -> None:
        connection = self.classic_connections.get(address)
        if connection is not None:
            connection.ssp_state.authenticated = True
            self.send_hci_packet(
                hci.HCI_Encryption_Change_Event(
                    status=0, connection_handle=connection.handle, encryption_enabled=enabled
                )
            )

    def on_hci_pin_code_request_negative_reply_command(self, command):
        return hci.HCI_StatusAndAddressReturnParameters(
            status=hci.HCI_ErrorCode.SUCCESS, bd_addr=command.bd_addr
        )

    def drop_classic(self, reason: int) -> None:
        """Ends every Classic link (a reset, or a host that went away)."""
        for connection in list(self.classic_connections.values()):
            try:
                self.send_lmp_packet(connection.peer_address, lmp.LmpDetach(reason))
            except Exception:  # the peer left the link already
                pass
            self.classic_connections.pop(connection.peer_address, None)
        if self.inquiry is not None:
            self.inquiry.cancel()
            self.inquiry = None


# -----------------------------------------------------------------------------
# A PlayStation pad
# -----------------------------------------------------------------------------
class PadPairing(PairingDelegate):
    def __init__(self) -> None:
        super().__init__(io_capability=PairingDelegate.IoCapability.NO_OUTPUT_NO_INPUT)


class PlayStationPad:
    def __init__(self, name: str, kind: str, address: str, link) -> None:
        if kind not in ("ds4", "dualsense"):
            raise ValueError(f"kind {kind}: ds4 or dualsense")
        self.name = name
        self.kind = kind
        self.address = hci.Address(address, hci.Address.PUBLIC_DEVICE_ADDRESS)
        self.controller = ClassicController(f"ps-{name}", link, public_address=self.address)
        config = DeviceConfiguration(
            name="Wireless Controller",
            address=self.address,
            classic_enabled=True,
            le_enabled=False,
            class_of_device=GAMEPAD_CLASS,
            discoverable=False,
            connectable=True,
        )
        self.device = Device(
            config=config, host=Host(self.controller, AsyncPipeSink(self.controller))
        )
        self.device.pairing_config_factory = lambda _connection: PairingConfig(
            sc=False, mitm=False, bonding=True, delegate=PadPairing()
        )
        self.controller.key_source = self.key_for
        self.hid = HidDevice(self.device)
        self.hid.register_get_report_cb(self.get_report)
        self.hid.on(HidDevice.EVENT_INTERRUPT_DATA, self.on_output)
        self.device.on(self.device.EVENT_CONNECTION, self.on_connection)
        self.connection = None
        self.host_address: hci.Address | None = None
        self.full_mode = False
        self.stuck_short = False
        self.garbled = False
        self.battery_status = 0x08
        self.silent = False
        self.streaming: asyncio.Task | None = None
        self.held: set[str] = set()
        self.axes = {"LX": 128, "LY": 128, "RX": 128, "RY": 128}
        self.triggers = {"L2": 0, "R2": 0}
        self.sequence = 0

    async def key_for(self, address) -> bytes | None:
        return await self.device.get_link_key(address)

    async def power_on(self) -> None:
        await self.device.power_on()

    # -- the link -------------------------------------------------------------
    def on_connection(self, connection) -> None:
        if connection.transport != PhysicalTransport.BR_EDR:
            return
        self.connection = connection
        self.full_mode = False
        event("connected", self.name, connection.peer_address)
        connection.on(
            connection.EVENT_DISCONNECTION,
            lambda reason: self.on_disconnection(connection, reason),
        )
        connection.on(connection.EVENT_LINK_KEY, lambda: self.on_paired(connection))
        connection.on(
            connection.EVENT_CONNECTION_ENCRYPTION_CHANGE,
            lambda: event("encrypted", self.name, int(connection.is_encrypted)),
        )

    def on_paired(self, connection) -> None:
        self.host_address = connection.peer_address
        event("paired", self.name)
        # Out of pairing mode once paired.
        asyncio.get_running_loop().create_task(self.device.set_discoverable(False))

    def on_disconnection(self, connection, reason) -> None:
        if self.connection is connection:
            self.connection = None
        self.stop_streaming()
        # Bumble closes no channel of a link that broke: forget them, so that nothing is
        # sent on them on the next link.
        self.hid.l2cap_ctrl_channel = None
        self.hid.l2cap_intr_channel = None
        event("disconnected", self.name, int(reason))

    async def page_host(self, address) -> None:
        """Switched on: page the host, then open the HID channels."""
        try:
            connection = await self.device.connect(
                address, transport=PhysicalTransport.BR_EDR, timeout=10
            )
        except Exception as error:  # page timeout, or the host rejected us
            event("page-failed", self.name, type(error).__name__)
            return
        try:
            await asyncio.wait_for(self.wait_encrypted(connection), 10)
            await self.hid.connect_control_channel()
            await self.hid.connect_interrupt_channel()
        except Exception as error:  # the host dropped us meanwhile
            event("open-failed", self.name, type(error).__name__)

    async def wait_encrypted(self, connection) -> None:
        while not connection.is_encrypted:
            if self.connection is not connection:
                raise RuntimeError("disconnected")
            await asyncio.sleep(0.01)

    def stop_streaming(self) -> None:
        if self.streaming is not None:
            self.streaming.cancel()
            self.streaming = None

    # -- HID --------------------------------------------------------------------
    def get_report(self, report_id: int, report_type: int, _buffer_size: int):
        features = {0x05: 41, 0x02: 37} if self.kind == "ds4" else {0x05: 41}
        if report_type != 3 or report_id not in features:
            return HidDevice.GetSetStatus(status=HidDevice.GetSetReturn.REPORT_ID_NOT_FOUND)
        body = bytes(features[report_id] - 4)
        data = body + crc32(0xA3, bytes([report_id]) + body)
        if not self.stuck_short:
            self.full_mode = True
        event("feature-read", self.name, f"0x{report_id:02x}")
        return HidDevice.GetSetStatus(data=data, status=HidDevice.GetSetReturn.SUCCESS)

    def on_output(self, pdu: bytes) -> None:
        pdu = bytes(pdu)
        if len(pdu) != 79 or pdu[0] != 0xA2:
            event("output-refused", self.name, len(pdu))
            return
        if crc32(0xA2, pdu[1:75]) != pdu[75:79]:
            event("output-bad-crc", self.name)
            return
        rgb = pdu[9:12] if self.kind == "ds4" else pdu[48:51]
        event("lightbar", self.name, *rgb)

    def buttons(self) -> bytes:
        values = [HAT[frozenset(self.held & {"UP", "DOWN", "LEFT", "RIGHT"})], 0, 0]
        for button in self.held:
            if button in BUTTONS:
                index, bit = BUTTONS[button]
                values[index] |= bit
        return bytes(values)

    def report(self) -> bytes:
        """The next input report, without the 0xA1 header."""
        sticks = bytes(self.axes[a] for a in ("LX", "LY", "RX", "RY"))
        triggers = bytes([self.triggers["L2"], self.triggers["R2"]])
        if not self.full_mode:
            return bytes([0x01]) + sticks + self.buttons() + triggers
        self.sequence = (self.sequence + 1) & 0xFF
        report = bytearray(74)
        if self.kind == "ds4":
            report[0:3] = bytes([0x11, 0xC0, 0x00])
            report[3:7] = sticks
            report[7:10] = self.buttons()
            report[10:12] = triggers
            report[32] = self.battery_status
        else:
            report[0:2] = bytes([0x31, self.sequence])
            report[2:6] = sticks
            report[6:8] = triggers
            report[9:12] = self.buttons()
            report[54] = self.battery_status
        crc = crc32(0xA1, bytes(report))
        if self.garbled:
            crc = bytes(b ^ 0xFF for b in crc)
        return bytes(report) + crc

    async def stream(self) -> None:
        while True:
            if not self.silent and self.hid.l2cap_intr_channel is not None:
                try:
                    self.hid.send_data(self.report())
                except Exception as error:  # the link went meanwhile
                    event("send-failed", self.name, type(error).__name__)
            await asyncio.sleep(REPORT_PERIOD_MS / 1000)

    def check_streaming(self) -> None:
        encrypted = self.connection is not None and self.connection.is_encrypted
        if self.streaming is None and encrypted and self.hid.l2cap_intr_channel is not None:
            self.streaming = asyncio.get_running_loop().create_task(self.stream())
            event("streaming", self.name)


def axis_value(value: float, name: str) -> int:
    value = max(-1.0, min(1.0, value))
    if name in ("LY", "RY"):  # Y = 0 is forward
        value = -value
    return max(0, min(255, round(128 + value * 127)))


class ClassicPads:
    """The PlayStation pads on the link and their commands."""

    def __init__(self, link) -> None:
        self.link = link
        self.pads: dict[str, PlayStationPad] = {}
        asyncio.get_event_loop()

    def robot(self, server):
        return server.controller

    async def create(self, name: str, kind: str, address: str) -> None:
        if name in self.pads:
            raise ValueError(f"pad {name} exists")
        pad = PlayStationPad(name, kind.lower(), address, self.link)
        await pad.power_on()
        self.pads[name] = pad
        asyncio.get_running_loop().create_task(self.watch(pad))

    async def watch(self, pad: PlayStationPad) -> None:
        """Starts the report stream once the interrupt channel is open."""
        while pad.name in self.pads:
            if pad.connection is not None:
                pad.check_streaming()
            await asyncio.sleep(0.01)

    async def command(self, words: list[str], server) -> str:
        name = words[1]
        pad = self.pads[name]
        match words:
            case ["pairing", _]:
                await pad.device.set_discoverable(True)
            case ["on", _, *address]:
                host = (
                    hci.Address(address[0], hci.Address.PUBLIC_DEVICE_ADDRESS)
                    if address
                    else pad.host_address
                )
                if host is None:
                    raise RuntimeError("not paired: give the address to page")
                asyncio.get_running_loop().create_task(pad.page_host(host))
            case ["off", _]:
                pad.stop_streaming()
                if pad.connection is not None:
                    await pad.connection.disconnect(
                        hci.HCI_ErrorCode.REMOTE_DEVICE_TERMINATED_CONNECTION_DUE_TO_POWER_OFF_ERROR
                    )
            case ["press" | "release" as action, _, *buttons]:
                for button in buttons:
                    button = button.upper()
                    if button not in BUTTONS and button not in ("UP", "DOWN", "LEFT", "RIGHT"):
                        raise ValueError(f"no button {button}")
                    if action == "press":
                        pad.held.add(button)
                    else:
                        pad.held.discard(button)
            case ["stick", _, axis, value]:
                pad.axes[axis.upper()] = axis_value(float(value), axis.upper())
            case ["trigger", _, trigger, value]:
                trigger = trigger.upper()
                pad.triggers[trigger] = round(max(0.0, min(1.0, float(value))) * 255)
                if pad.triggers[trigger] > 0:
                    pad.held.add(trigger)
                else:
                    pad.held.discard(trigger)
            case ["lose", _]:
                # Answered at once: the link breaks now, the timeouts play out later.
                asyncio.get_running_loop().create_task(self.lose(pad, server.controller))
            case ["silent", _]:
                pad.silent = True
            case ["talk", _]:
                pad.silent = False
            case ["short", _]:
                pad.stuck_short = True
            case ["garble", _]:
                pad.garbled = True
            case ["battery", _, status]:
                pad.battery_status = int(status, 16)
            case ["forget", _]:
                await pad.device.keystore.delete_all()
            case ["state", _]:
                mode = "full" if pad.full_mode else "short"
                return ("connected " if pad.connection else "idle ") + mode
            case _:
                raise ValueError(f"unknown command: {' '.join(words)}")
        return ""

    async def lose(self, pad: PlayStationPad, robot) -> None:
        """Out of range: nothing passes; each side reports Connection Timeout after its
        supervision timeout (the robot's is the one it set as central)."""
        pad.stop_streaming()
        reason = hci.HCI_ErrorCode.CONNECTION_TIMEOUT_ERROR
        for address, connection in list(pad.controller.classic_connections.items()):
            del pad.controller.classic_connections[address]
            robot_connection = None
            if robot is not None:
                robot_connection = robot.classic_connections.pop(pad.address, None)
            timeout_ms = 20_000
            if robot_connection is not None:
                timeout_ms = robot.supervision_ms(robot_connection.handle)
            event("losing", pad.name, timeout_ms)
            await asyncio.sleep(timeout_ms / 1000)
            pad.controller.send_hci_packet(
                hci.HCI_Disconnection_Complete_Event(
                    status=0, connection_handle=connection.handle, reason=reason
                )
            )
            if robot_connection is not None and robot.host is not None:
                robot.send_hci_packet(
                    hci.HCI_Disconnection_Complete_Event(
                        status=0, connection_handle=robot_connection.handle, reason=reason
                    )
                )
            event("lost", pad.name, timeout_ms)
