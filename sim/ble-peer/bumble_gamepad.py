#!/usr/bin/env python3
"""A virtual Bluetooth LE gamepad for the base controller's remote, on Google's Bumble.

Bumble runs virtual Bluetooth controllers on one in-process link, with no radio and no
kernel Bluetooth. This program puts two kinds of them on a link:

- the robot's controller: an HCI transport (H4 over TCP) that a Bluetooth host opens,
  the simulator or the tests (`--hci tcp:127.0.0.1:PORT`). Every TCP client gets a
  fresh controller, as a rebooted chip would;
- gamepads: Bumble devices serving HID over GATT with the Report Map of an Xbox
  Wireless Controller (BLE firmware 5), the way the real pad does.

The pads are scripted by lines on stdin; each command is answered with `ok ...` or
`error ...` on stdout, and what happens on the link is printed as `event ...` lines
(see COMMANDS below). The tests in sim/tests/ble.rs drive it; a person can too.

Bumble 0.0.236's virtual controller has four defects that a Bluetooth host meets at
once; the robot's controller here fixes them (see RobotController).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys

try:
    from bumble import hci, ll
    from bumble.controller import Controller
    from bumble.core import AdvertisingData, UUID
    from bumble.device import Device
    from bumble.gatt import Characteristic, Descriptor, Service
    from bumble.host import Host
    from bumble.link import LocalLink
    from bumble.pairing import PairingConfig, PairingDelegate
    from bumble.transport.common import AsyncPipeSink

    from classic_pads import COMMANDS as CLASSIC_COMMANDS
    from classic_pads import ROBOT_PUBLIC_ADDRESS, ClassicController, ClassicPads
except ImportError as error:  # pragma: no cover - reported to the caller
    print(f"error bumble is not importable: {error}", flush=True)
    sys.exit(3)

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_REPORT_MAP = os.path.join(
    REPO, "core", "tests", "data", "hid", "xbox-wireless-ble-fw5_045E-0B13.hex"
)

COMMANDS = """\
pad NAME ADDRESS        create a powered pad with this random static address (no bond)
advertise NAME          start connectable advertising as a gamepad (again after each
                        disconnection, as a pad that is on does)
stop NAME               stop advertising
press NAME BUTTON...    hold buttons (A B X Y LB RB VIEW MENU XBOX LS RS) and notify
release NAME BUTTON...  let buttons go and notify
stick NAME AXIS VALUE   move LX LY RX RY to VALUE (-1.0 .. 1.0, +LY = forward) and notify
trigger NAME LT|RT VALUE pull a trigger (0.0 .. 1.0) and notify
disconnect NAME         the pad closes its link and stops advertising (switched off)
lose NAME               the link breaks (out of range): both sides see a supervision timeout
forget NAME             the pad forgets its bond
remove NAME             the pad leaves the link (powered off)
params NAME TIMEOUT_MS  the pad asks for new connection parameters (L2CAP request)
greedy NAME TIMEOUT_MS  from now on the pad asks for them as soon as it is connected
refuse NAME             from now on the pad refuses to pair (Pairing Not Supported)
inject NAME CID HEX     the pad sends this L2CAP PDU (payload in hex, '-' for none) on
                        channel CID now
attack NAME WHEN CID HEX from now on the pad sends this PDU on every link at WHEN:
                        `connect` (as soon as it is connected) or `key-missing` (right
                        after it answered the robot's encryption without a key)
peace NAME              no more attacks from this pad
away NAME               the pad leaves radio range (links time out), keeping its bond
back NAME               the pad is in range again (advertise it again)
state NAME              print the pad's connection state
quit                    end the program
"""
# PlayStation pads over Bluetooth Classic (classic_pads.py); a pad's name selects it.
COMMANDS += CLASSIC_COMMANDS

UUID_HID = UUID.from_16_bits(0x1812)
UUID_DEVICE_INFORMATION = UUID.from_16_bits(0x180A)
UUID_HID_INFORMATION = UUID.from_16_bits(0x2A4A)
UUID_REPORT_MAP = UUID.from_16_bits(0x2A4B)
UUID_HID_CONTROL_POINT = UUID.from_16_bits(0x2A4C)
UUID_REPORT = UUID.from_16_bits(0x2A4D)
UUID_PNP_ID = UUID.from_16_bits(0x2A50)
UUID_REPORT_REFERENCE = UUID.from_16_bits(0x2908)
GAMEPAD_APPEARANCE = 0x03C4

# Button bits of the Xbox BLE input report (bytes 13..15, bit 0 = button 1).
BUTTONS = {
    "A": 0, "B": 1, "X": 3, "Y": 4, "LB": 6, "RB": 7,
    "VIEW": 10, "MENU": 11, "XBOX": 12, "LS": 13, "RS": 14,
}


def event(*words: object) -> None:
    print("event", *words, flush=True)


def reply(*words: object) -> None:
    print(*words, flush=True)


def read_hex(path: str) -> bytes:
    with open(path, encoding="ascii") as file:
        text = " ".join(line for line in file if not line.startswith("#"))
    return bytes(int(pair, 16) for pair in text.split())


# -----------------------------------------------------------------------------
# The robot's controller, with Bumble 0.0.236's defects fixed
# -----------------------------------------------------------------------------
class RobotController(ClassicController):
    """The controller the Bluetooth host opens over TCP, with the Classic parts of
    ClassicController (a fixed public address, so that a Classic pad's bond holds).

    (a) Bumble answers a legacy scan with extended advertising reports whenever the
        controller claims extended advertising; a host that scans with the legacy
        commands then sees no advertisement. This controller does not claim it.
    (b) LE Create Connection Cancel is a no-op in Bumble: the pending connection stays,
        and every later LE Create Connection is refused. Here it ends the pending
        connection with LE Connection Complete, status Unknown Connection Identifier.
    (c) LE Remove Device From Resolving List gets no reply at all in Bumble, and the
        host waits for ever: here it succeeds.
    (d) HCI Reset is a no-op in Bumble, so connections survive a host reboot: here it
        drops every connection and the pending one (each TCP client also gets a fresh
        controller).
    """

    def __init__(self, name: str, link: LocalLink, sink) -> None:
        super().__init__(name, link, sink, ROBOT_PUBLIC_ADDRESS)
        self.le_features &= ~hci.LeFeatureMask.LE_EXTENDED_ADVERTISING  # (a)
        self.supervision_timeouts: dict[hci.Address, int] = {}

    # (b)
    def on_hci_le_create_connection_cancel_command(self, command):
        pending = self.pending_le_connection
        if pending is None:
            return hci.HCI_StatusReturnParameters(
                hci.HCI_ErrorCode.COMMAND_DISALLOWED_ERROR
            )
        self.pending_le_connection = None
        event("central-connect-cancel")
        # After the Command Complete of the cancel, as a real controller does.
        asyncio.get_running_loop().call_soon(
            self.send_hci_packet,
            hci.HCI_LE_Connection_Complete_Event(
                status=hci.HCI_ErrorCode.UNKNOWN_CONNECTION_IDENTIFIER_ERROR,
                connection_handle=0,
                role=hci.Role.CENTRAL,
                peer_address_type=pending.peer_address.address_type,
                peer_address=pending.peer_address,
                connection_interval=0,
                peripheral_latency=0,
                supervision_timeout=0,
                central_clock_accuracy=0,
            ),
        )
        return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS)

    # (c) Bumble has no class for this command, so a returned status would not even
    # be sent: complete it here.
    def on_hci_le_remove_device_from_resolving_list_command(self, command):
        self.send_hci_packet(
            hci.HCI_Command_Complete_Event(
                num_hci_command_packets=1,
                command_opcode=command.op_code,
                return_parameters=hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.SUCCESS),
            )
        )

    # (d)
    def on_hci_reset_command(self, command):
        self.drop_everything(hci.HCI_ErrorCode.REMOTE_USER_TERMINATED_CONNECTION_ERROR)
        self.le_scan_enable = False
        self.classic_scan_enable = 0
        return super().on_hci_reset_command(command)

    def drop_everything(self, reason: int) -> None:
        """Ends every connection; the peers see `reason`, this host nothing (it reset)."""
        self.pending_le_connection = None
        for connection in list(self.le_connections.values()):
            try:
                connection.send_ll_control_pdu(ll.TerminateInd(reason))
            except Exception:  # the peer left the link already
                pass
            del self.le_connections[connection.peer_address]
        self.drop_classic(reason)

    def on_hci_le_create_connection_command(self, command):
        event("central-connect", command.peer_address, command.supervision_timeout * 10)
        return super().on_hci_le_create_connection_command(command)

    def create_le_connection(self, peer_address) -> None:
        pending = self.pending_le_connection
        if pending is not None:
            self.supervision_timeouts[pending.peer_address] = pending.supervision_timeout
        super().create_le_connection(peer_address)

    def on_hci_le_connection_update_command(self, command):
        event("central-params", command.supervision_timeout * 10)
        connection = self.find_le_connection_by_handle(command.connection_handle)
        if connection is not None:
            self.supervision_timeouts[connection.peer_address] = command.supervision_timeout
        return super().on_hci_le_connection_update_command(command)

    def on_hci_le_set_scan_enable_command(self, command):
        if bool(command.le_scan_enable) != self.le_scan_enable:
            event("central-scan", "on" if command.le_scan_enable else "off")
        return super().on_hci_le_set_scan_enable_command(command)

    def on_hci_acl_data_packet(self, packet) -> None:
        # A Security Manager Pairing Request from the host (L2CAP channel 6, code 1),
        # the start of a pairing on the robot's side. Unfragmented on this link.
        data = bytes(packet.data)
        if len(data) >= 5 and data[2:4] == b"\x06\x00" and data[4] == 0x01:
            event("central-pairing-request")
        super().on_hci_acl_data_packet(packet)

    def on_hci_le_enable_encryption_command(self, command):
        event("central-encrypt")
        return super().on_hci_le_enable_encryption_command(command)


class HciServer:
    """H4 over TCP: one client at a time, each with a fresh RobotController."""

    def __init__(self, link: LocalLink) -> None:
        self.link = link
        self.controller: RobotController | None = None
        self.clients = 0

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        if self.controller is not None:
            self.retire(self.controller)
        self.clients += 1

        class Sink:
            def on_packet(self, packet: bytes) -> None:
                if not writer.is_closing():
                    writer.write(packet)

        controller = RobotController(f"robot{self.clients}", self.link, Sink())
        self.controller = controller
        event("host-connected", self.clients)
        try:
            while True:
                kind = await reader.readexactly(1)
                if kind == b"\x01":  # command: opcode (2), length (1)
                    header = await reader.readexactly(3)
                    body = await reader.readexactly(header[2])
                elif kind == b"\x02":  # ACL: handle (2), length (2)
                    header = await reader.readexactly(4)
                    body = await reader.readexactly(int.from_bytes(header[2:4], "little"))
                else:
                    event("host-garbage", kind.hex())
                    break
                controller.on_packet(kind + header + body)
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            if self.controller is controller:
                self.retire(controller)
                self.controller = None
            writer.close()
            event("host-disconnected")

    def retire(self, controller: RobotController) -> None:
        # A host that went away is a chip that lost power: its links time out.
        controller.drop_everything(hci.HCI_ErrorCode.CONNECTION_TIMEOUT_ERROR)
        controller.host = None
        if controller in self.link.controllers:
            self.link.remove_controller(controller)


# -----------------------------------------------------------------------------
# A HID-over-GATT gamepad
# -----------------------------------------------------------------------------
class PadDelegate(PairingDelegate):
    def __init__(self, pad: "Pad") -> None:
        super().__init__(io_capability=PairingDelegate.IoCapability.NO_OUTPUT_NO_INPUT)
        self.pad = pad

    async def accept(self) -> bool:
        if self.pad.refuse_pairing:
            event("pairing-refused", self.pad.name)
            return False
        return True


class Pad:
    def __init__(self, name: str, address: str, link: LocalLink, report_map: bytes):
        self.name = name
        self.controller = Controller(f"pad-{name}", link=link)
        self.device = Device(
            name="Xbox Wireless Controller",
            address=hci.Address(address, hci.Address.RANDOM_DEVICE_ADDRESS),
            host=Host(self.controller, AsyncPipeSink(self.controller)),
        )
        self.refuse_pairing = False
        self.params_on_connect: int | None = None
        # WHEN -> (channel, payload): raw L2CAP PDUs this pad sends on every link.
        self.attacks: dict[str, tuple[int, bytes]] = {}
        host = self.device.host
        find_key = host.long_term_key_provider

        async def key_for_robot(handle, rand, ediv):
            key = await find_key(handle, rand, ediv) if find_key else None
            if key is None:
                asyncio.create_task(self.fire_after_answer("key-missing"))
            return key

        host.long_term_key_provider = key_for_robot
        self.device.pairing_config_factory = lambda _connection: PairingConfig(
            sc=True,
            mitm=False,
            bonding=True,
            delegate=PadDelegate(self),
        )
        self.connection = None
        self.buttons = 0
        self.axes = {"LX": 0x8000, "LY": 0x8000, "RX": 0x8000, "RY": 0x8000}
        self.triggers = {"LT": 0, "RT": 0}
        encrypted = Characteristic.READ_REQUIRES_ENCRYPTION
        self.input_report = Characteristic(
            UUID_REPORT,
            Characteristic.Properties.READ | Characteristic.Properties.NOTIFY,
            Characteristic.READABLE | encrypted,
            self.report(),
            descriptors=[
                Descriptor(UUID_REPORT_REFERENCE, Descriptor.READABLE, bytes([1, 1]))
            ],
        )
        output_report = Characteristic(
            UUID_REPORT,
            Characteristic.Properties.READ
            | Characteristic.Properties.WRITE
            | Characteristic.Properties.WRITE_WITHOUT_RESPONSE,
            Characteristic.READABLE | Characteristic.WRITEABLE | encrypted,
            bytes(8),
            descriptors=[
                Descriptor(UUID_REPORT_REFERENCE, Descriptor.READABLE, bytes([3, 2]))
            ],
        )
        self.device.add_services(
            [
                Service(
                    UUID_HID,
                    [
                        Characteristic(
                            UUID_HID_INFORMATION,
                            Characteristic.Properties.READ,
                            Characteristic.READABLE | encrypted,
                            bytes([0x11, 0x01, 0x00, 0x02]),
                        ),
                        Characteristic(
                            UUID_REPORT_MAP,
                            Characteristic.Properties.READ,
                            Characteristic.READABLE | encrypted,
                            report_map,
                        ),
                        self.input_report,
                        output_report,
                        Characteristic(
                            UUID_HID_CONTROL_POINT,
                            Characteristic.Properties.WRITE_WITHOUT_RESPONSE,
                            Characteristic.WRITEABLE | Characteristic.WRITE_REQUIRES_ENCRYPTION,
                            bytes(1),
                        ),
                    ],
                ),
                Service(
                    UUID_DEVICE_INFORMATION,
                    [
                        Characteristic(
                            UUID_PNP_ID,
                            Characteristic.Properties.READ,
                            Characteristic.READABLE,
                            bytes([0x02, 0x5E, 0x04, 0x13, 0x0B, 0x01, 0x05]),
                        )
                    ],
                ),
            ]
        )
        self.device.advertising_data = bytes(
            AdvertisingData(
                [
                    (AdvertisingData.FLAGS, bytes([0x06])),
                    (AdvertisingData.APPEARANCE, GAMEPAD_APPEARANCE.to_bytes(2, "little")),
                    (AdvertisingData.INCOMPLETE_LIST_OF_16_BIT_SERVICE_CLASS_UUIDS, bytes(UUID_HID)),
                    (AdvertisingData.COMPLETE_LOCAL_NAME, b"Xbox Wireless Controller"),
                ]
            )
        )
        self.device.on(self.device.EVENT_CONNECTION, self.on_connection)
        self.device.on("characteristic_subscription", self.on_subscription)

    async def power_on(self) -> None:
        await self.device.power_on()

    def on_connection(self, connection) -> None:
        self.connection = connection
        name = self.name
        event("connected", name, connection.peer_address)
        connection.on(
            connection.EVENT_DISCONNECTION,
            lambda reason: self.on_disconnection(connection, reason),
        )
        connection.on(connection.EVENT_PAIRING_START, lambda: event("pairing-started", name))
        connection.on(connection.EVENT_PAIRING, lambda _keys: event("paired", name))
        connection.on(
            connection.EVENT_PAIRING_FAILURE,
            lambda reason: event("pairing-failed", name, reason),
        )
        connection.on(
            connection.EVENT_CONNECTION_ENCRYPTION_CHANGE,
            lambda: event("encrypted", name, int(connection.is_encrypted)),
        )
        connection.on(
            connection.EVENT_CONNECTION_ENCRYPTION_FAILURE,
            lambda error: event("encryption-failed", name, error),
        )
        connection.on(
            connection.EVENT_CONNECTION_PARAMETERS_UPDATE,
            lambda: event(
                "params", name, int(connection.parameters.supervision_timeout)
            ),
        )
        if self.params_on_connect is not None:
            asyncio.create_task(request_params(self, self.params_on_connect))
        if "connect" in self.attacks:
            asyncio.get_running_loop().call_soon(self.fire, "connect")

    async def fire_after_answer(self, when: str) -> None:
        # A few turns of the loop: the host sends the (negative) answer and the
        # controllers pass it on first, and the robot gets no time to hang up.
        for _ in range(3):
            await asyncio.sleep(0)
        self.fire(when)

    def fire(self, when: str) -> None:
        attack = self.attacks.get(when)
        if attack is None or self.connection is None:
            return
        channel, payload = attack
        self.inject(channel, payload)
        event("attacked", self.name, when, channel, payload.hex() or "-")

    def inject(self, channel: int, payload: bytes) -> None:
        if self.connection is None:
            raise RuntimeError("not connected")
        self.connection.send_l2cap_pdu(channel, payload)

    def on_subscription(self, _connection, characteristic, notify, _indicate) -> None:
        if characteristic is self.input_report and notify:
            event("subscribed", self.name)

    def on_disconnection(self, connection, reason) -> None:
        if self.connection is connection:
            self.connection = None
        event("disconnected", self.name, int(reason))

    def report(self) -> bytes:
        hat = 0
        data = bytearray()
        for axis in ("LX", "LY", "RX", "RY"):
            data += self.axes[axis].to_bytes(2, "little")
        for trigger in ("LT", "RT"):
            data += self.triggers[trigger].to_bytes(2, "little")
        data.append(hat)
        data += (self.buttons & 0x7FFF).to_bytes(2, "little")
        data.append(0)
        return bytes(data)

    async def notify(self) -> None:
        value = self.report()
        self.input_report.value = value
        if self.connection is None:
            raise RuntimeError("not connected")
        await self.device.notify_subscribers(self.input_report, value)


async def request_params(pad: Pad, timeout_ms: int) -> None:
    connection = pad.connection
    if connection is None:
        return
    event("params-asked", pad.name, timeout_ms)
    try:
        await connection.update_parameters(
            connection_interval_min=15,
            connection_interval_max=30,
            max_latency=0,
            supervision_timeout=timeout_ms,
            use_l2cap=True,
        )
    except Exception as error:  # the central refused or the link dropped
        event("params-refused", pad.name, type(error).__name__)


def parse_payload(text: str) -> bytes:
    return b"" if text == "-" else bytes.fromhex(text)


def axis_value(value: float, name: str) -> int:
    value = max(-1.0, min(1.0, value))
    # HID Y grows downwards: pushing the left stick forward is a small LY.
    if name in ("LY", "RY"):
        value = -value
    return max(0, min(0xFFFF, round(0x8000 + value * 0x7FFF)))


# -----------------------------------------------------------------------------
# The command loop
# -----------------------------------------------------------------------------
class Peer:
    def __init__(self, report_map: bytes) -> None:
        self.link = LocalLink()
        self.server = HciServer(self.link)
        self.pads: dict[str, Pad] = {}
        self.report_map = report_map
        self.classic = ClassicPads(self.link)

    def pad(self, name: str) -> Pad:
        if name not in self.pads:
            raise KeyError(f"no pad {name}")
        return self.pads[name]

    async def command(self, words: list[str]) -> str:
        if len(words) > 1 and words[1] in self.classic.pads:
            return await self.classic.command(words, self.server)
        match words:
            case ["ps", name, kind, address]:
                if name in self.pads:
                    raise ValueError(f"pad {name} exists")
                await self.classic.create(name, kind, address)
            case ["pad", name, address]:
                if name in self.pads:
                    raise ValueError(f"pad {name} exists")
                pad = Pad(name, address, self.link, self.report_map)
                await pad.power_on()
                self.pads[name] = pad
            case ["advertise", name]:
                await self.pad(name).device.start_advertising(
                    auto_restart=True,
                    advertising_interval_min=20.0,
                    advertising_interval_max=20.0,
                )
            case ["stop", name]:
                await self.pad(name).device.stop_advertising()
            case ["press" | "release" as action, name, *buttons]:
                pad = self.pad(name)
                for button in buttons:
                    bit = 1 << BUTTONS[button.upper()]
                    pad.buttons = pad.buttons | bit if action == "press" else pad.buttons & ~bit
                await pad.notify()
            case ["stick", name, axis, value]:
                pad = self.pad(name)
                pad.axes[axis.upper()] = axis_value(float(value), axis.upper())
                await pad.notify()
            case ["trigger", name, trigger, value]:
                pad = self.pad(name)
                pad.triggers[trigger.upper()] = round(max(0.0, min(1.0, float(value))) * 1023)
                await pad.notify()
            case ["disconnect", name]:
                pad = self.pad(name)
                if pad.connection is None:
                    raise RuntimeError("not connected")
                await pad.device.stop_advertising()
                await pad.connection.disconnect()
            case ["lose", name]:
                await self.lose(self.pad(name))
            case ["forget", name]:
                pad = self.pad(name)
                await pad.device.keystore.delete_all()
            case ["remove", name]:
                pad = self.pads.pop(name)
                await self.lose(pad, quiet=True)
                self.link.remove_controller(pad.controller)
            case ["params", name, timeout_ms]:
                pad = self.pad(name)
                if pad.connection is None:
                    raise RuntimeError("not connected")
                asyncio.create_task(request_params(pad, int(timeout_ms)))
            case ["greedy", name, timeout_ms]:
                self.pad(name).params_on_connect = int(timeout_ms)
            case ["refuse", name]:
                self.pad(name).refuse_pairing = True
            case ["inject", name, channel, payload]:
                self.pad(name).inject(int(channel, 0), parse_payload(payload))
            case ["attack", name, "connect" | "key-missing" as when, channel, payload]:
                self.pad(name).attacks[when] = (int(channel, 0), parse_payload(payload))
            case ["peace", name]:
                self.pad(name).attacks.clear()
            case ["away", name]:
                pad = self.pad(name)
                await self.lose(pad, quiet=True)
                self.link.remove_controller(pad.controller)
            case ["back", name]:
                self.link.add_controller(self.pad(name).controller)
            case ["state", name]:
                pad = self.pad(name)
                return "connected" if pad.connection else "idle"
            case ["help"]:
                return COMMANDS.replace("\n", " | ")
            case _:
                raise ValueError(f"unknown command: {' '.join(words)}")
        return ""

    async def lose(self, pad: Pad, quiet: bool = False) -> None:
        """Breaks the pad's links: after the supervision timeout both controllers report
        Connection Timeout, and nothing passes meanwhile."""
        await pad.device.stop_advertising()
        robot = self.server.controller
        for connection in list(pad.controller.le_connections.values()):
            peer = connection.peer_address
            own = connection.self_address
            robot_connection = None
            if robot is not None:
                for candidate in robot.le_connections.values():
                    if candidate.self_address == peer or candidate.peer_address == own:
                        robot_connection = candidate
            timeout_ms = 500
            if robot is not None and robot_connection is not None:
                timeout_ms = robot.supervision_timeouts.get(robot_connection.peer_address, 50) * 10
            # Out of range: no packet reaches either side any more.
            del pad.controller.le_connections[peer]
            if robot_connection is not None:
                del robot.le_connections[robot_connection.peer_address]
            await asyncio.sleep(timeout_ms / 1000)
            reason = hci.HCI_ErrorCode.CONNECTION_TIMEOUT_ERROR
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
            if not quiet:
                event("lost", pad.name, timeout_ms)


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--hci", default="127.0.0.1:0",
                        help="HOST:PORT for the robot's HCI transport (port 0: any free one)")
    parser.add_argument("--report-map", default=DEFAULT_REPORT_MAP,
                        help="the pads' HID Report Map (.hex, '#' lines are comments)")
    parser.add_argument("--log", default="WARNING", help="Python log level")
    args = parser.parse_args()
    logging.basicConfig(level=args.log.upper(), stream=sys.stderr)

    peer = Peer(read_hex(args.report_map))
    host, port = args.hci.rsplit(":", 1)
    server = await asyncio.start_server(peer.server.serve, host, int(port))
    port = server.sockets[0].getsockname()[1]
    reply("hci", f"tcp:{host}:{port}")

    loop = asyncio.get_running_loop()
    lines: asyncio.Queue[str | None] = asyncio.Queue()

    def read_stdin() -> None:
        for line in sys.stdin:
            loop.call_soon_threadsafe(lines.put_nowait, line)
        loop.call_soon_threadsafe(lines.put_nowait, None)

    loop.run_in_executor(None, read_stdin)
    while (line := await lines.get()) is not None:
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if words == ["quit"]:
            break
        try:
            answer = await peer.command(words)
            reply("ok", words[0], answer)
        except Exception as error:  # every command gets an answer
            reply("error", words[0], f"{type(error).__name__}: {error}")
    server.close()
    os._exit(0)


if __name__ == "__main__":
    asyncio.run(main())
