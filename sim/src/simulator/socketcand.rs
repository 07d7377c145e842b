//! The simulator's network endpoint: the socketcand protocol (CAN over TCP, as the
//! `socketcand` daemon of linux-can serves a SocketCAN interface) to any number of
//! clients at once. python-can (`interface="socketcand"`), `cantools monitor` through
//! python-can, and `basectl --interface socketcand` connect to it.
//!
//! A session: the server greets with `< hi >`, the client opens the bus with
//! `< open can0 >` and switches to raw mode with `< rawmode >`, each answered
//! `< ok >`. From then on the server sends every frame on the bus as
//! `< frame ID SECS.USECS DATA >` and the client sends with `< send ID LEN B0 B1 … >`.
//!
//! Threads do the blocking I/O: one accepts connections, and each client has a reader
//! (handshake, then its frames) and a writer fed by a bounded queue. The bus hub in
//! the simulator's executor gets [`Event`]s and hands each client the frames it must
//! see through [`Client::offer`]; a client whose queue is full has stopped reading,
//! and is disconnected so that it never holds up the bus or the other clients.

use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use embedded_can::{ExtendedId, Frame, Id, StandardId};

use crate::can::SimFrame;
use crate::runtime::QueueSender;
use crate::simulator::wire_queue::{CreditToken, NODE_TRANSMIT_QUEUE, NodeCredit};

/// Where the simulator listens unless told otherwise (socketcand's own default port
/// is 29536 as well).
pub const DEFAULT_ADDRESS: &str = "127.0.0.1:29536";
/// The one bus the simulator serves.
pub const BUS_NAME: &str = "can0";
/// Messages that may wait for one client: about 3 s of the controller's traffic. A
/// client this far behind is disconnected.
pub const CLIENT_QUEUE: usize = 1024;
/// The kernel's send buffer per client, bytes (about 1000 frames).
const SEND_BUFFER: usize = 32 * 1024;
/// The longest message a client may send between `<` and `>`.
pub const MAX_MESSAGE: usize = 128;
/// After `< ok >` to `< rawmode >`, frames wait this long, so that a client reading
/// the `< ok >` with one `recv` (python-can compares it whole) gets it alone.
const RAWMODE_SETTLE: Duration = Duration::from_millis(50);

/// One message a client sent, the text between `<` and `>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    Open(String),
    RawMode,
    Send(SimFrame),
    Echo,
}

/// Why a client's message was not understood.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RequestError {
    Unknown(String),
    /// `send` whose ID, length or data bytes are not a CAN frame.
    BadFrame(String),
}

impl core::fmt::Display for RequestError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RequestError::Unknown(text) => write!(f, "unknown command \"< {text} >\""),
            RequestError::BadFrame(why) => write!(f, "bad send: {why}"),
        }
    }
}

/// Parses the text between `<` and `>`.
pub fn parse_request(body: &str) -> Result<Request, RequestError> {
    let words: Vec<&str> = body.split_whitespace().collect();
    match words.as_slice() {
        ["open", bus] => Ok(Request::Open((*bus).to_owned())),
        ["rawmode"] => Ok(Request::RawMode),
        ["echo"] => Ok(Request::Echo),
        ["send", id, length, data @ ..] => parse_send(id, length, data).map(Request::Send),
        _ => Err(RequestError::Unknown(body.trim().to_owned())),
    }
}

/// `send ID LEN B…`: the ID in hex, 8 digits for an extended frame (as socketcand
/// decides), the length in hex (0–8) and that many bytes in hex.
fn parse_send(id: &str, length: &str, data: &[&str]) -> Result<SimFrame, RequestError> {
    let bad = |why: String| RequestError::BadFrame(why);
    let number = u32::from_str_radix(id, 16).map_err(|_| bad(format!("ID {id:?} is not hex")))?;
    let id = if id.len() == 8 {
        ExtendedId::new(number)
            .map(Id::Extended)
            .ok_or_else(|| bad(format!("extended ID {number:#x} is wider than 29 bits")))?
    } else {
        u16::try_from(number)
            .ok()
            .and_then(StandardId::new)
            .map(Id::Standard)
            .ok_or_else(|| bad(format!("standard ID {number:#x} is wider than 11 bits")))?
    };
    let length = usize::from_str_radix(length, 16)
        .ok()
        .filter(|length| *length <= 8)
        .ok_or_else(|| bad(format!("length {length:?} is not 0 to 8")))?;
    if data.len() != length {
        return Err(bad(format!(
            "length {length} but {} data bytes",
            data.len()
        )));
    }
    let mut bytes = [0; 8];
    for (byte, text) in bytes.iter_mut().zip(data) {
        *byte = u8::from_str_radix(text, 16)
            .ok()
            .filter(|_| text.len() <= 2)
            .ok_or_else(|| bad(format!("data byte {text:?} is not hex")))?;
    }
    SimFrame::new(id, &bytes[..length]).ok_or_else(|| bad("not a CAN frame".to_owned()))
}

/// A frame as socketcand sends it in raw mode: the ID in 3 hex digits (standard) or
/// 8 (extended), the time in seconds and microseconds, the data as one hex string.
pub fn format_frame(frame: &SimFrame, time: Duration) -> String {
    let id = match frame.id() {
        Id::Standard(id) => format!("{:03X}", id.as_raw()),
        Id::Extended(id) => format!("{:08X}", id.as_raw()),
    };
    let data: String = frame
        .data()
        .iter()
        .map(|byte| format!("{byte:02X}"))
        .collect();
    format!(
        "< frame {id} {}.{:06} {data} >",
        time.as_secs(),
        time.subsec_micros()
    )
}

/// What the clients' threads tell the bus hub.
pub enum Event {
    /// A client finished its handshake: from now on it sees the bus.
    Joined(Client),
    /// A client sent a frame onto the bus; `credit` is its place in the client's
    /// queue for the wire ([`crate::simulator::wire_queue`]).
    Frame {
        client: u64,
        frame: SimFrame,
        credit: CreditToken,
    },
    /// A client sent something the server does not understand; it stays connected.
    Refused { client: u64, why: String },
    /// A client went away (closed, or its connection failed).
    Left { client: u64, why: String },
}

/// A connected client in raw mode, as the hub holds it.
pub struct Client {
    pub id: u64,
    pub address: SocketAddr,
    queue: SyncSender<String>,
    stream: TcpStream,
}

impl Client {
    /// Queues `message` for the client. False if its queue is full: the client has
    /// stopped reading, and the caller disconnects it.
    pub fn offer(&self, message: String) -> bool {
        match self.queue.try_send(message) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => false,
        }
    }

    /// Closes the connection; the client's threads end on it.
    pub fn disconnect(&self) {
        let _ = self.stream.shutdown(Shutdown::Both);
    }
}

/// The time stamp of a frame: wall-clock time since the Unix epoch, as socketcand
/// stamps frames with the kernel's receive time.
pub fn wall_time() -> Duration {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default()
}

/// Binds `address` and accepts clients on a thread of its own until the process
/// ends. Fails only if the address cannot be bound.
pub fn serve(address: SocketAddr, events: QueueSender<Event>) -> io::Result<SocketAddr> {
    let listener = TcpListener::bind(address)?;
    let bound = listener.local_addr()?;
    thread::Builder::new()
        .name("socketcand".into())
        .spawn(move || {
            let mut next_id = 1;
            for stream in listener.incoming() {
                let Ok(stream) = stream else { continue };
                let id = next_id;
                next_id += 1;
                let events = events.clone();
                let _ = thread::Builder::new()
                    .name(format!("socketcand-{id}"))
                    .spawn(move || serve_client(id, stream, events));
            }
        })?;
    Ok(bound)
}

/// One client: the handshake, then its messages until it closes.
fn serve_client(id: u64, stream: TcpStream, events: QueueSender<Event>) {
    let Ok(address) = stream.peer_addr() else {
        return;
    };
    let left = |why: String| events.send(Event::Left { client: id, why });
    // Small messages, each one answer: send them at once.
    let _ = stream.set_nodelay(true);
    // A fixed send buffer instead of the kernel's growing one: what a client has not
    // read waits in the bounded queue, where the hub sees it.
    let _ = nix::sys::socket::setsockopt(&stream, nix::sys::socket::sockopt::SndBuf, &SEND_BUFFER);
    let (Ok(mut writer), Ok(reader)) = (stream.try_clone(), stream.try_clone()) else {
        return;
    };
    let mut messages = Messages::new(BufReader::new(reader));
    if writer.write_all(b"< hi >").is_err() {
        return;
    }
    // Handshake: open the bus, then raw mode. Anything else is answered with an error.
    let mut opened = false;
    loop {
        let body = match messages.next() {
            Ok(Some(body)) => body,
            Ok(None) => return,
            Err(error) => {
                let _ = writer.write_all(format!("< error {error} >").as_bytes());
                return;
            }
        };
        let reply = match parse_request(&body) {
            Ok(Request::Open(bus)) if bus == BUS_NAME => {
                opened = true;
                "< ok >".to_owned()
            }
            Ok(Request::Open(bus)) => {
                format!("< error no bus {bus}; the simulator serves {BUS_NAME} >")
            }
            Ok(Request::RawMode) if opened => break,
            Ok(Request::Echo) => "< echo >".to_owned(),
            Ok(_) if !opened => format!("< error open {BUS_NAME} first >"),
            Ok(_) => "< error only rawmode is served >".to_owned(),
            Err(error) => format!("< error {error} >"),
        };
        if writer.write_all(reply.as_bytes()).is_err() {
            return;
        }
    }
    // Join the bus before saying so: every frame sent after the client learns it is
    // in raw mode must reach it. What comes meanwhile waits in its queue.
    let (queue, outgoing) = sync_channel(CLIENT_QUEUE);
    let Ok(hub_stream) = stream.try_clone() else {
        return;
    };
    events.send(Event::Joined(Client {
        id,
        address,
        queue,
        stream: hub_stream,
    }));
    if writer.write_all(b"< ok >").is_err() {
        return left("closed during the handshake".to_owned());
    }
    let _ = thread::Builder::new()
        .name(format!("socketcand-{id}-out"))
        .spawn(move || write_frames(writer, outgoing));
    // While the client has a full queue of frames waiting for the wire, it is not read.
    let credit = NodeCredit::new(NODE_TRANSMIT_QUEUE);
    loop {
        match messages.next() {
            Ok(Some(body)) => match parse_request(&body) {
                Ok(Request::Send(frame)) => events.send(Event::Frame {
                    client: id,
                    frame,
                    credit: credit.take(),
                }),
                Ok(Request::Echo) => {
                    // Answered through the hub's queue would reorder it; echo is rare
                    // and harmless to drop for a client that is this busy.
                    events.send(Event::Refused {
                        client: id,
                        why: "echo in raw mode is not served".to_owned(),
                    });
                }
                Ok(other) => events.send(Event::Refused {
                    client: id,
                    why: format!("{other:?} in raw mode"),
                }),
                Err(error) => events.send(Event::Refused {
                    client: id,
                    why: error.to_string(),
                }),
            },
            Ok(None) => return left("closed by the client".to_owned()),
            Err(error) => return left(error.to_string()),
        }
    }
}

fn write_frames(mut writer: TcpStream, outgoing: Receiver<String>) {
    thread::sleep(RAWMODE_SETTLE);
    let mut batch = String::new();
    while let Ok(message) = outgoing.recv() {
        // Whatever else waits goes out in the same write: one system call for a burst.
        batch.clear();
        batch.push_str(&message);
        while batch.len() < 16 * 1024
            && let Ok(message) = outgoing.try_recv()
        {
            batch.push_str(&message);
        }
        if writer.write_all(batch.as_bytes()).is_err() {
            return;
        }
    }
}

/// Cuts a byte stream into the bodies of `< … >` messages.
struct Messages<R> {
    reader: R,
}

impl<R: BufRead> Messages<R> {
    fn new(reader: R) -> Self {
        Self { reader }
    }

    /// The next message's body; `None` at the end of the stream; an error for a
    /// message longer than [`MAX_MESSAGE`] or text outside the brackets.
    fn next(&mut self) -> io::Result<Option<String>> {
        let mut skipped = Vec::new();
        self.reader.read_until(b'<', &mut skipped)?;
        match skipped.pop() {
            None => return Ok(None),
            Some(b'<') => {}
            // The stream ended within text outside a message.
            Some(_) => return Ok(None),
        }
        if skipped.iter().any(|byte| !byte.is_ascii_whitespace()) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "text outside < >",
            ));
        }
        let mut body = Vec::new();
        Read::by_ref(&mut self.reader)
            .take(MAX_MESSAGE as u64 + 1)
            .read_until(b'>', &mut body)?;
        match body.pop() {
            Some(b'>') => {}
            None => return Ok(None),
            Some(_) if body.len() >= MAX_MESSAGE => {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("message longer than {MAX_MESSAGE} characters"),
                ));
            }
            Some(_) => return Ok(None),
        }
        String::from_utf8(body)
            .map(Some)
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "message is not ASCII"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn standard(id: u16, data: &[u8]) -> SimFrame {
        SimFrame::standard(id, data).unwrap()
    }

    #[test]
    fn the_handshake_and_pythons_send_lines_parse() {
        assert_eq!(
            parse_request(" open can0 "),
            Ok(Request::Open("can0".into()))
        );
        assert_eq!(parse_request(" rawmode "), Ok(Request::RawMode));
        // python-can writes the length and bytes in hex without padding.
        assert_eq!(
            parse_request(" send 0C8 5 2c 1 0 0 3 "),
            Ok(Request::Send(standard(0x0C8, &[0x2C, 1, 0, 0, 3])))
        );
        assert_eq!(
            parse_request(" send 006 0  "),
            Ok(Request::Send(standard(0x006, &[])))
        );
        let extended = parse_request(" send 18FF0001 1 ff ").unwrap();
        let Request::Send(frame) = extended else {
            panic!("{extended:?}")
        };
        assert!(frame.is_extended());
        assert_eq!(frame.data(), [0xFF]);
    }

    #[test]
    fn bad_sends_say_what_is_wrong() {
        for (body, why) in [
            (" send 800 0 ", "wider than 11 bits"),
            (" send 3FFFFFFF 0 ", "wider than 29 bits"),
            (" send 0C8 9 ", "not 0 to 8"),
            (" send 0C8 2 1 ", "2 but 1 data bytes"),
            (" send 0C8 1 100 ", "not hex"),
            (" send xyz 0 ", "not hex"),
        ] {
            let error = parse_request(body).unwrap_err().to_string();
            assert!(error.contains(why), "{body}: {error}");
        }
        assert_eq!(
            parse_request(" bcmmode "),
            Err(RequestError::Unknown("bcmmode".into()))
        );
    }

    #[test]
    fn frames_are_formatted_as_socketcand_sends_them() {
        let time = Duration::from_micros(1_700_000_000_000_042);
        assert_eq!(
            format_frame(&standard(0x0EE, &[0x24, 0x8D]), time),
            "< frame 0EE 1700000000.000042 248D >"
        );
        assert_eq!(
            format_frame(&standard(0x006, &[]), Duration::from_secs(3)),
            "< frame 006 3.000000  >"
        );
        let extended = SimFrame::new(Id::Extended(ExtendedId::new(0x1234).unwrap()), &[1]).unwrap();
        assert_eq!(
            format_frame(&extended, Duration::ZERO),
            "< frame 00001234 0.000000 01 >"
        );
    }

    #[test]
    fn messages_are_cut_from_a_stream_in_any_pieces() {
        let stream = b"< open can0 >\n< rawmode >< send 006 1 1 >";
        let mut messages = Messages::new(&stream[..]);
        assert_eq!(messages.next().unwrap().as_deref(), Some(" open can0 "));
        assert_eq!(messages.next().unwrap().as_deref(), Some(" rawmode "));
        assert_eq!(messages.next().unwrap().as_deref(), Some(" send 006 1 1 "));
        assert_eq!(messages.next().unwrap(), None);
    }

    #[test]
    fn an_endless_message_or_stray_text_is_an_error_not_a_hang() {
        let long = format!("< {} >", "a".repeat(500));
        assert!(Messages::new(long.as_bytes()).next().is_err());
        assert!(Messages::new(&b"hello < rawmode >"[..]).next().is_err());
    }
}
