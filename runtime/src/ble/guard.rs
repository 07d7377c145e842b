//! The HCI controller as the BLE host sees it: the real controller behind the guard
//! (`base_bluetooth::guard`). Every event and ACL packet the controller sends is shown
//! to the guard first; a packet it refuses never reaches trouble-host, and a link it
//! closes is disconnected here with HCI Disconnect ([`GuardState::close_links`]), and
//! the host's own commands for that link are kept from the controller meanwhile.
//! Every other command and all outgoing data pass unchanged.

use core::cell::RefCell;

use bt_hci::cmd::link_control::Disconnect;
use bt_hci::cmd::{AsyncCmd, SyncCmd};
use bt_hci::controller::{Controller, ControllerCmdAsync, ControllerCmdSync};
use bt_hci::data::{AclPacket, IsoPacket, SyncPacket};
use bt_hci::event::{Event, EventPacket};
use bt_hci::param::{ConnHandle, DisconnectReason};
use bt_hci::{ControllerToHostPacket, cmd};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;

use base_bluetooth::guard::{self, AclVerdict, Counters, Guard};
use bt_hci::WriteHci;

/// Links the guard follows at once: more than the host's one, so that a link the
/// controller opens beside it is still followed (and closed if it misbehaves).
pub const GUARD_LINKS: usize = 4;

/// The largest HCI packet body the wrapper hands on (an event's 255 parameter bytes
/// plus its header, or an ACL packet of the controller's buffer).
const PACKET_BUFFER: usize = 259;

/// The guard's state, shared by the wrapper (which reads), the remote task (which
/// opens and closes the pairing window) and [`Self::close_links`].
pub struct GuardState {
    guard: Mutex<NoopRawMutex, RefCell<Guard<GUARD_LINKS>>>,
    to_close: Signal<NoopRawMutex, ()>,
}

impl Default for GuardState {
    fn default() -> Self {
        Self::new()
    }
}

impl GuardState {
    pub const fn new() -> Self {
        Self {
            guard: Mutex::new(RefCell::new(Guard::new())),
            to_close: Signal::new(),
        }
    }

    pub fn set_pairing_window(&self, open: bool) {
        self.guard
            .lock(|guard| guard.borrow_mut().set_pairing_window(open));
    }

    pub fn counters(&self) -> Counters {
        self.guard.lock(|guard| guard.borrow().counters())
    }

    /// Sends HCI Disconnect for every link the guard closes; runs for ever beside the
    /// host's runner (the command's answer arrives through the runner's reads).
    pub async fn close_links<C: ControllerCmdSync<Disconnect>>(&self, controller: &C) -> ! {
        loop {
            self.to_close.wait().await;
            while let Some(handle) = self
                .guard
                .lock(|guard| guard.borrow_mut().next_link_to_close())
            {
                warn!(
                    "remote: closing link {=u16}, guard {}",
                    handle,
                    self.counters()
                );
                let disconnect = Disconnect::new(
                    ConnHandle::new(handle),
                    DisconnectReason::RemoteUserTerminatedConn,
                );
                if controller.exec(&disconnect).await.is_err() {
                    // The link went away meanwhile; its Disconnection Complete ends it.
                    warn!("remote: disconnecting link {=u16} failed", handle);
                }
            }
        }
    }

    fn count_malformed_event(&self) {
        warn!("remote: dropped a malformed event from the controller");
        self.guard
            .lock(|guard| guard.borrow_mut().count_malformed_event());
    }

    fn is_closing(&self, handle: u16) -> bool {
        self.guard.lock(|guard| guard.borrow().is_closing(handle))
    }

    fn on_event(&self, event: &EventPacket<'_>) -> bool {
        self.guard
            .lock(|guard| guard.borrow_mut().on_event(event.kind.0, event.data))
    }

    fn on_acl(&self, acl: &AclPacket<'_>) -> AclVerdict {
        let verdict = self.guard.lock(|guard| {
            guard.borrow_mut().on_acl(
                acl.handle().raw(),
                acl.boundary_flag() as u8,
                acl.broadcast_flag() as u8,
                acl.data(),
            )
        });
        match verdict {
            AclVerdict::Deliver(_) => {}
            AclVerdict::Drop(rule) => {
                debug!("remote: guard dropped a packet: {}", rule);
            }
            AclVerdict::Close(rule) => {
                warn!(
                    "remote: guard refused a packet on link {=u16}: {}",
                    acl.handle().raw(),
                    rule
                );
                self.to_close.signal(());
            }
        }
        verdict
    }
}

/// The controller `C` with the guard in front of what it sends to the host.
pub struct GuardedController<'g, C> {
    inner: &'g C,
    state: &'g GuardState,
}

impl<'g, C> GuardedController<'g, C> {
    pub fn new(inner: &'g C, state: &'g GuardState) -> Self {
        Self { inner, state }
    }
}

impl<C: embedded_io::ErrorType> embedded_io::ErrorType for GuardedController<'_, C> {
    type Error = C::Error;
}

impl<C: Controller> Controller for GuardedController<'_, C> {
    type Buffer<'a> = [u8; PACKET_BUFFER];

    fn alloc_buf(&self) -> Result<Self::Buffer<'_>, Self::Error> {
        Ok([0; PACKET_BUFFER])
    }

    async fn write_acl_data(&self, packet: &AclPacket<'_>) -> Result<(), Self::Error> {
        self.inner.write_acl_data(packet).await
    }

    async fn write_sync_data(&self, packet: &SyncPacket<'_>) -> Result<(), Self::Error> {
        self.inner.write_sync_data(packet).await
    }

    async fn write_iso_data(&self, packet: &IsoPacket<'_>) -> Result<(), Self::Error> {
        self.inner.write_iso_data(packet).await
    }

    /// The controller's next packet the guard lets through, copied into `buf` (the
    /// controller's own buffer is reused for the packets that are dropped).
    async fn read<'a>(
        &self,
        buf: &'a mut Self::Buffer<'_>,
    ) -> Result<ControllerToHostPacket<'a>, Self::Error> {
        let mut received = self.inner.alloc_buf()?;
        loop {
            match self.inner.read(&mut received).await? {
                ControllerToHostPacket::Event(event) => {
                    // trouble-host unwraps the parse of most events.
                    if Event::try_from(event.clone()).is_err() {
                        self.state.count_malformed_event();
                        continue;
                    }
                    if !self.state.on_event(&event) {
                        continue;
                    }
                    let data = copy_into(buf, event.data);
                    return Ok(ControllerToHostPacket::Event(EventPacket {
                        kind: event.kind,
                        data,
                    }));
                }
                ControllerToHostPacket::Acl(acl) => {
                    if let AclVerdict::Deliver(_) = self.state.on_acl(&acl) {
                        let (handle, boundary, broadcast) =
                            (acl.handle(), acl.boundary_flag(), acl.broadcast_flag());
                        let data = copy_into(buf, acl.data());
                        return Ok(ControllerToHostPacket::Acl(AclPacket::new(
                            handle, boundary, broadcast, data,
                        )));
                    }
                }
                // No LE link of ours carries audio or isochronous data.
                ControllerToHostPacket::Sync(_) | ControllerToHostPacket::Iso(_) => {}
            }
        }
    }
}

/// `data` copied to the front of `buf`, cut at its end (no HCI packet body is longer).
fn copy_into<'a>(buf: &'a mut [u8; PACKET_BUFFER], data: &[u8]) -> &'a [u8] {
    let len = data.len().min(PACKET_BUFFER);
    buf[..len].copy_from_slice(&data[..len]);
    &buf[..len]
}

impl<C> GuardedController<'_, C> {
    /// Whether `command` is about a link the guard is closing: the host's command
    /// stays here, as the guard's Disconnect ends that link anyway. (A controller
    /// refuses a second Disconnect of a link already ending, or an encryption on it,
    /// and trouble-host 0.8 stops altogether on such an answer.)
    fn for_closing_link<Command: cmd::Cmd + ?Sized>(&self, command: &Command) -> bool {
        let mut params = FirstBytes::default();
        let _ = command.params().write_hci(&mut params);
        guard::command_link(Command::OPCODE.to_raw(), params.bytes())
            .is_some_and(|handle| self.state.is_closing(handle))
    }
}

impl<C, Command> ControllerCmdSync<Command> for GuardedController<'_, C>
where
    C: ControllerCmdSync<Command>,
    Command: SyncCmd + ?Sized,
{
    async fn exec(&self, command: &Command) -> Result<Command::Return, cmd::Error<Self::Error>> {
        if self.for_closing_link(command) {
            // The answer trouble-host takes in its stride for a link that is gone.
            return Err(cmd::Error::Hci(
                bt_hci::param::Error::UNKNOWN_CONN_IDENTIFIER,
            ));
        }
        self.inner.exec(command).await
    }
}

impl<C, Command> ControllerCmdAsync<Command> for GuardedController<'_, C>
where
    C: ControllerCmdAsync<Command>,
    Command: AsyncCmd + ?Sized,
{
    async fn exec(&self, command: &Command) -> Result<(), cmd::Error<Self::Error>> {
        if self.for_closing_link(command) {
            // Taken: what it waits for never comes, the link's Disconnection Complete
            // ends the wait (trouble-host 0.8 stops on any error here).
            return Ok(());
        }
        self.inner.exec(command).await
    }
}

/// The first two bytes a command's parameters write (where a link's handle is).
#[derive(Default)]
struct FirstBytes {
    bytes: [u8; 2],
    len: usize,
}

impl FirstBytes {
    fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

impl embedded_io::ErrorType for FirstBytes {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for FirstBytes {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let take = buf.len().min(self.bytes.len() - self.len);
        self.bytes[self.len..self.len + take].copy_from_slice(&buf[..take]);
        self.len += take;
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
