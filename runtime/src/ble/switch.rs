//! Bluetooth off after a panic loop ([`base_core::panic_loop`]): the remote task does
//! not start, so nothing touches the radio, until the controller turns Bluetooth on
//! again (a confirm press of the front button, or `command` = `BLUETOOTH_ON_KEY`). The
//! rest of the base runs as always meanwhile; the controller reports the state in
//! register 36, `bluetooth_off`.

use embassy_sync::signal::Signal;

use base_core::panic_loop::Bluetooth;

use super::RemoteRequest;
use crate::sync::RawMutex;

/// Waits until the remote may start: at once if `bluetooth` is on; after a panic loop,
/// until a request from the controller says Bluetooth was turned on, then calls
/// `turned_on` (which forgets the panics where they survive resets). The last request
/// is signalled again for the remote task, so that it sees the pairing window as the
/// controller left it.
pub async fn wait_until_on(
    bluetooth: Bluetooth,
    requests: &Signal<RawMutex, RemoteRequest>,
    turned_on: impl FnOnce(),
) {
    if bluetooth == Bluetooth::On {
        return;
    }
    warn!("Bluetooth off after a panic loop: a confirm press or command 0xB1E1 turns it on");
    loop {
        let request = requests.wait().await;
        if request.turn_ons != 0 {
            info!("Bluetooth turned on: the remote starts");
            turned_on();
            requests.signal(request);
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::cell::Cell;
    use core::pin::pin;
    use embassy_futures::poll_once;

    #[test]
    fn with_bluetooth_on_the_remote_starts_at_once_and_nothing_is_forgotten() {
        let requests = Signal::new();
        let forgotten = Cell::new(false);
        let waiting = pin!(wait_until_on(Bluetooth::On, &requests, || forgotten.set(true)));
        assert!(poll_once(waiting).is_ready());
        assert!(!forgotten.get());
    }

    #[test]
    fn after_a_panic_loop_only_the_turn_on_request_starts_the_remote() {
        let requests = Signal::new();
        let forgotten = Cell::new(false);
        let mut waiting = pin!(wait_until_on(Bluetooth::OffAfterPanics, &requests, || {
            forgotten.set(true)
        }));
        assert!(poll_once(waiting.as_mut()).is_pending());
        let pairing = RemoteRequest {
            pairing_open: true,
            ..RemoteRequest::default()
        };
        requests.signal(pairing);
        assert!(
            poll_once(waiting.as_mut()).is_pending(),
            "a pairing window is no turn-on"
        );
        assert!(!forgotten.get());
        let on = RemoteRequest {
            turn_ons: 1,
            ..pairing
        };
        requests.signal(on);
        assert!(poll_once(waiting.as_mut()).is_ready());
        assert!(forgotten.get());
        assert_eq!(
            requests.try_take(),
            Some(on),
            "the remote task gets the request too"
        );
    }
}
