//! The Bluetooth remote on the host: the firmware's own BLE central
//! (`base_runtime::ble::run`, trouble-host) and its PlayStation pad host over
//! Bluetooth Classic (`base_runtime::classic::run`) on one Bluetooth controller
//! reached through an HCI transport, H4 over TCP, shared through the HCI splitter as
//! on the ESP32.
//!
//! ```text
//!   ble::run ─── trouble-host ── ExternalController ── LeTransport ──┐
//!   classic::run ─── Classic host ──────────────────── ClassicPort ──┴─ SerialTransport ──TCP── HCI controller
//!                                                                        (Bumble's virtual one, or a USB
//!                                                                         dongle behind Bumble's HCI bridge)
//! ```
//!
//! The transport is `bt-hci-serial`'s `SerialTransport`, the same one a UART-attached
//! controller would use; its byte streams here are a TCP socket. A reader thread moves
//! the received bytes to the wall-clock executor ([`crate::runtime::block_on_realtime`]),
//! so the remote runs with real time, as the controller on the other side does.

use std::io::{self, Read as _, Write as _};
use std::net::TcpStream;
use std::path::{Path, PathBuf};

use base_runtime::ble as remote;
use base_runtime::channels::Channels;
use base_runtime::classic;
use bt_hci::cmd::le::LeSetScanParams;
use bt_hci::controller::ControllerCmdSync;
use bt_hci_serial::SerialTransport;
use embassy_futures::join::join;
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use trouble_host::prelude::{Address, BondInformation, Identity, LongTermKey, SecurityLevel};

use crate::file_flash::FileFlash;
use crate::flash::{ERASE_SIZE, RamFlash};
use crate::robot::{Pc, RtcRam, VirtualRobot};
use crate::runtime::{QueueReceiver, block_on, block_on_realtime, cross_thread_queue};
use base_core::panic_loop::Bluetooth;

/// HCI commands the host may have in flight at once.
pub const HCI_SLOTS: usize = 8;

/// The remote's bond partition: two pages, as on the chip.
pub const BOND_FLASH_SIZE: usize = 2 * ERASE_SIZE;

/// The robot's own Bluetooth address (random static), as the chip derives it from its MAC.
pub const ROBOT_MAC: [u8; 6] = [0x02, 0xB0, 0x75, 0x00, 0x00, 0x01];

/// The controller's HCI transport (H4 over TCP).
pub type HciTransport = SerialTransport<NoopRawMutex, HciReader, HciWriter>;

/// The Bluetooth controller behind its transport, as the remotes share it.
pub struct HostController {
    transport: HciTransport,
}

/// Why a transport could not be opened or broke.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HciError(pub io::ErrorKind);

impl core::fmt::Display for HciError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "HCI transport: {}", self.0)
    }
}

impl core::error::Error for HciError {}

impl embedded_io::Error for HciError {
    fn kind(&self) -> embedded_io::ErrorKind {
        match self.0 {
            io::ErrorKind::UnexpectedEof => embedded_io::ErrorKind::BrokenPipe,
            _ => embedded_io::ErrorKind::Other,
        }
    }
}

/// Where the HCI controller is: `tcp:HOST:PORT` (H4 over TCP).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HciSpec {
    Tcp(String),
}

impl HciSpec {
    /// Parses `tcp:HOST:PORT`; anything else gets a message saying what is accepted.
    pub fn parse(text: &str) -> Result<HciSpec, String> {
        match text.strip_prefix("tcp:") {
            Some(address)
                if address.rsplit_once(':').is_some_and(|(host, port)| {
                    !host.is_empty() && port.parse::<u16>().is_ok()
                }) =>
            {
                Ok(HciSpec::Tcp(address.to_owned()))
            }
            _ => Err(format!(
                "`{text}` is no HCI transport: give tcp:HOST:PORT (H4 over TCP, e.g. tcp:127.0.0.1:9001)"
            )),
        }
    }
}

/// Opens the transport and makes the controller trouble-host drives.
pub fn open(spec: &HciSpec) -> io::Result<HostController> {
    let HciSpec::Tcp(address) = spec;
    let stream = TcpStream::connect(address)?;
    stream.set_nodelay(true)?;
    let writer = HciWriter {
        stream: stream.try_clone()?,
    };
    let reader = HciReader::spawn(stream);
    Ok(HostController {
        transport: SerialTransport::new(reader, writer),
    })
}

/// Runs both remote tasks on `controller` for ever: the BLE central and the
/// PlayStation pad host, through the HCI splitter, their bonds in `bond_flash`.
pub async fn run_remotes<F: NorFlash + Clone>(
    controller: HostController,
    bond_flash: F,
    channels: &Channels,
) -> ! {
    classic::run_both::<_, _, HCI_SLOTS>(
        &controller.transport,
        remote::random_static_address(&ROBOT_MAC),
        bond_flash,
        0..BOND_FLASH_SIZE as u32,
        channels.remote_ends(),
    )
    .await
}

/// Bytes from the controller: a thread reads the socket and hands the chunks over.
pub struct HciReader {
    chunks: QueueReceiver<Result<Vec<u8>, io::ErrorKind>>,
    pending: Vec<u8>,
    start: usize,
}

impl HciReader {
    fn spawn(mut stream: TcpStream) -> HciReader {
        let (sender, chunks) = cross_thread_queue();
        std::thread::spawn(move || {
            let mut buffer = [0u8; 1024];
            loop {
                match stream.read(&mut buffer) {
                    Ok(0) => return,
                    Ok(n) => sender.send(Ok(buffer[..n].to_vec())),
                    Err(error) if error.kind() == io::ErrorKind::Interrupted => {}
                    Err(error) => {
                        sender.send(Err(error.kind()));
                        return;
                    }
                }
            }
        });
        HciReader {
            chunks,
            pending: Vec::new(),
            start: 0,
        }
    }
}

impl embedded_io::ErrorType for HciReader {
    type Error = HciError;
}

impl embedded_io_async::Read for HciReader {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, HciError> {
        if buf.is_empty() {
            return Ok(0);
        }
        while self.start == self.pending.len() {
            match self.chunks.receive().await {
                Some(Ok(chunk)) => {
                    self.pending = chunk;
                    self.start = 0;
                }
                Some(Err(kind)) => return Err(HciError(kind)),
                // The controller closed the connection.
                None => return Ok(0),
            }
        }
        let n = buf.len().min(self.pending.len() - self.start);
        buf[..n].copy_from_slice(&self.pending[self.start..self.start + n]);
        self.start += n;
        Ok(n)
    }
}

/// Bytes to the controller: written straight to the socket (a few bytes per packet, on
/// a local connection).
pub struct HciWriter {
    stream: TcpStream,
}

impl embedded_io::ErrorType for HciWriter {
    type Error = HciError;
}

impl embedded_io_async::Write for HciWriter {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, HciError> {
        self.stream
            .write(buf)
            .map_err(|error| HciError(error.kind()))
    }

    async fn flush(&mut self) -> Result<(), HciError> {
        self.stream.flush().map_err(|error| HciError(error.kind()))
    }
}

impl Drop for HciWriter {
    fn drop(&mut self) {
        // The reader thread holds the other handle: close the connection for both, so
        // the controller sees the host go away (a chip losing power) and the thread ends.
        let _ = self.stream.shutdown(std::net::Shutdown::Both);
    }
}

/// A robot with the Bluetooth remote: the virtual robot's hardware plus the bond's
/// flash partition, which outlives a run as the chip's flash does.
pub struct RemoteRobot {
    pub robot: VirtualRobot,
    pub bond_flash: RamFlash,
}

impl Default for RemoteRobot {
    fn default() -> Self {
        Self::new()
    }
}

impl RemoteRobot {
    pub fn new() -> Self {
        Self {
            robot: VirtualRobot::new(),
            bond_flash: RamFlash::new(BOND_FLASH_SIZE),
        }
    }

    /// Boots the controller with the remote on `controller`, on the wall clock, and runs
    /// `script` beside them; the controller loses power when the script returns (the
    /// HCI connection closes with it).
    pub fn run<T>(&self, controller: HostController, script: impl AsyncFnOnce(&Pc) -> T) -> T {
        block_on_realtime(async {
            let (hardware, pc) = self.robot.boot();
            let bluetooth = hardware.bluetooth;
            let channels = Channels::new();
            let firmware = join(
                base_runtime::run(hardware, self.robot.settings, &channels),
                async {
                    remote::wait_until_on(bluetooth, &channels.remote_requests, || {
                        self.robot.rtc_ram.turned_on()
                    })
                    .await;
                    run_remotes(controller, self.bond_flash.clone(), &channels).await
                },
            );
            match select(firmware, script(&pc)).await {
                Either::First((never, _)) => never,
                Either::Second(result) => result,
            }
        })
    }

    /// Bonds the BLE pad at `address` (random static, least significant byte first)
    /// ahead of the next boot, as if it had paired: its record in the bond partition.
    pub fn bond_ble_pad(&self, address: [u8; 6]) {
        let identity = Identity {
            addr: Address::random(address),
            irk: None,
        };
        let mut bond = BondInformation::new(
            identity,
            LongTermKey::new(0x0BAD_F00D_0123_4567_89AB_CDEF_B1E0_0001),
            SecurityLevel::Encrypted,
            true,
        );
        bond.encryption_key_len = 16;
        let mut flash = self.bond_flash.clone();
        block_on(remote::store_bond(
            &mut flash,
            0..BOND_FLASH_SIZE as u32,
            &bond,
        ))
        .expect("the bond partition takes a record");
    }

    /// [`Self::run`] on the virtual clock, for a controller that lives on the same
    /// executor ([`crate::fake_hci`]): waits cost no wall time.
    pub fn run_virtual<C, T>(&self, controller: C, script: impl AsyncFnOnce(&Pc) -> T) -> T
    where
        C: trouble_host::Controller + ControllerCmdSync<LeSetScanParams>,
    {
        block_on(self.boot(controller, script))
    }

    /// The BLE remote alone on `controller` (no splitter: a controller without Classic).
    async fn boot<C, T>(&self, controller: C, script: impl AsyncFnOnce(&Pc) -> T) -> T
    where
        C: trouble_host::Controller + ControllerCmdSync<LeSetScanParams>,
    {
        let (hardware, pc) = self.robot.boot();
        let bluetooth = hardware.bluetooth;
        let channels = Channels::new();
        let address = remote::random_static_address(&ROBOT_MAC);
        let bond_flash = self.bond_flash.clone();
        {
            let firmware = join(
                base_runtime::run(hardware, self.robot.settings, &channels),
                async {
                    remote::wait_until_on(bluetooth, &channels.remote_requests, || {
                        self.robot.rtc_ram.turned_on()
                    })
                    .await;
                    remote::run(
                        controller,
                        address,
                        bond_flash,
                        0..BOND_FLASH_SIZE as u32,
                        channels.remote_ends(),
                    )
                    .await
                },
            );
            match select(firmware, script(&pc)).await {
                Either::First((never, _)) => never,
                Either::Second(result) => result,
            }
        }
    }
}

/// The live simulator's remote (`--hci`): the controller, and the bond in a file beside
/// the register flash, so a paired pad stays paired across restarts.
pub struct LiveRemote {
    controller: HostController,
    bond_flash: FileFlash,
    pub bond_path: PathBuf,
}

impl LiveRemote {
    /// Opens the transport and the bond file (next to `flash_path`, `.bond` added).
    pub fn open(spec: &HciSpec, flash_path: &Path) -> io::Result<LiveRemote> {
        let mut bond_path = flash_path.as_os_str().to_owned();
        bond_path.push(".bond");
        let bond_path = PathBuf::from(bond_path);
        let bond_flash = FileFlash::open(&bond_path, BOND_FLASH_SIZE)?;
        let controller = open(spec).map_err(|error| {
            io::Error::new(
                error.kind(),
                format!("HCI transport {spec:?} does not answer: {error}"),
            )
        })?;
        Ok(LiveRemote {
            controller,
            bond_flash,
            bond_path,
        })
    }
}

/// Runs the remote if there is one, once Bluetooth is on (`bluetooth`, the boot's
/// panic-loop decision); without one, waits for ever (the base runs without a remote,
/// as a chip without its radio does).
pub async fn run_live_remote(
    remote: Option<LiveRemote>,
    bluetooth: Bluetooth,
    rtc_ram: &RtcRam,
    channels: &Channels,
) {
    remote::wait_until_on(bluetooth, &channels.remote_requests, || rtc_ram.turned_on()).await;
    match remote {
        Some(remote) => run_remotes(remote.controller, remote.bond_flash, channels).await,
        None => core::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_tcp_host_port_is_an_hci_transport() {
        assert_eq!(
            HciSpec::parse("tcp:127.0.0.1:9001"),
            Ok(HciSpec::Tcp("127.0.0.1:9001".into()))
        );
        for wrong in [
            "127.0.0.1:9001",
            "tcp:127.0.0.1",
            "tcp::9001",
            "tcp:host:99999",
            "usb:0",
        ] {
            let error = HciSpec::parse(wrong).unwrap_err();
            assert!(error.contains("tcp:HOST:PORT"), "{wrong}: {error}");
        }
    }
}
